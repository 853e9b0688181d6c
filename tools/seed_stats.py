#!/usr/bin/env python3
"""Per-seed and over-seed figures of `fsrl eval` reports (docs/REPRODUCTION.md's arm tables).

    python3 tools/seed_stats.py A.json B.json C.json [--vs X.json Y.json Z.json] [--setting S]

Prints each report's success, then the arm's mean +- std with a 95 % t interval over seeds and
the means of Coll., Timeout, Nav. Time and Disc. With --vs, a Welch t-test of the success means
(two-sided p, Student t via the regularized incomplete beta; no scipy needed).
"""
import argparse
import json
import math
import statistics


def row(path, setting):
    """The setting's figures from one report (its first subject)."""
    d = json.load(open(path))
    for s in d["subjects"][0]["settings"]:
        if setting is None or s["setting"] == setting:
            return s
    raise SystemExit(f"{path}: no setting {setting}")


def betacf(a, b, x):
    """Continued fraction of the incomplete beta (Numerical Recipes, 6.4)."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > 1e-300 else 1e-300)
    h = d
    for m in range(1, 300):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > 1e-300 else 1e-300)
        c = 1.0 + aa / c
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > 1e-300 else 1e-300)
        c = 1.0 + aa / c
        de = d * c
        h *= de
        if abs(de - 1.0) < 1e-12:
            break
    return h


def betai(a, b, x):
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    lb = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
    bt = math.exp(lb + a * math.log(x) + b * math.log(1.0 - x))
    if x < (a + 1.0) / (a + b + 2.0):
        return bt * betacf(a, b, x) / a
    return 1.0 - bt * betacf(b, a, 1.0 - x) / b


def t_two_sided_p(t, df):
    return betai(df / 2.0, 0.5, df / (df + t * t))


def t_quantile_975(df):
    """The 0.975 quantile of Student's t by bisection on the two-sided p."""
    lo, hi = 0.0, 100.0
    for _ in range(200):
        mid = (lo + hi) / 2.0
        if t_two_sided_p(mid, df) > 0.05:
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2.0


def arm(paths, setting):
    rows = [row(p, setting) for p in paths]
    succ = [r["success"] for r in rows]
    mean = statistics.mean(succ)
    sd = statistics.stdev(succ) if len(succ) > 1 else 0.0
    n = len(succ)
    half = t_quantile_975(n - 1) * sd / math.sqrt(n) if n > 1 else float("nan")
    avg = lambda k: statistics.mean(r[k] for r in rows)
    print(" / ".join(f"{s:.3f}" for s in succ), end="")
    print(f" | {mean:.3f} ± {sd:.3f} [{mean - half:.2f}, {mean + half:.2f}]", end="")
    print(
        f" | Coll. {avg('collision'):.3f} | Timeout {avg('timeout'):.3f}"
        f" | Nav. {avg('nav_time_s'):.2f} | Disc. {avg('disc'):.3f}"
        f" | pooled {sum(r['successes'] for r in rows)}/{sum(r['episodes'] for r in rows)}"
    )
    return succ


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reports", nargs="+")
    ap.add_argument("--vs", nargs="+", default=[])
    ap.add_argument("--setting", default=None)
    a = ap.parse_args()
    x = arm(a.reports, a.setting)
    if a.vs:
        y = arm(a.vs, a.setting)
        vx, vy = statistics.variance(x) / len(x), statistics.variance(y) / len(y)
        t = (statistics.mean(x) - statistics.mean(y)) / math.sqrt(vx + vy)
        df = (vx + vy) ** 2 / (vx**2 / (len(x) - 1) + vy**2 / (len(y) - 1))
        print(f"Welch: difference {statistics.mean(x) - statistics.mean(y):+.3f}, t = {t:.2f}, df = {df:.1f}, p = {t_two_sided_p(abs(t), df):.3f}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Experiments C1 and C3 over their three seeds (docs/CROWDS.md): success per seed, mean ± sd,
and Welch's t-test over seeds against a reference arm, from the committed eval reports.
    python3 docs/results/crowds/seeds.py
Only the standard library: Student's t CDF through the regularised incomplete beta function."""
import json
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
CROWDS = ["orca-20", "orca-10", "social-force-10", "social-force-20"]
LABEL = {"orca-20": "20 ORCA", "orca-10": "10 ORCA", "social-force-10": "10 SF", "social-force-20": "20 SF"}


def betacf(a, b, x):
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > 1e-300 else 1e-300)
    h = d
    for m in range(1, 300):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > 1e-300 else 1e-300)
        c = 1.0 + aa / c if abs(1.0 + aa / c) > 1e-300 else 1e-300
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > 1e-300 else 1e-300)
        c = 1.0 + aa / c if abs(1.0 + aa / c) > 1e-300 else 1e-300
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-12:
            break
    return h


def betainc(a, b, x):
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    lbeta = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
    front = math.exp(lbeta + a * math.log(x) + b * math.log(1.0 - x))
    if x < (a + 1.0) / (a + b + 2.0):
        return front * betacf(a, b, x) / a
    return 1.0 - front * betacf(b, a, 1.0 - x) / b


def welch_p(x, y):
    """Two-sided p of Welch's t-test; None when both samples have no spread."""
    nx, ny = len(x), len(y)
    mx, my = sum(x) / nx, sum(y) / ny
    vx = sum((v - mx) ** 2 for v in x) / (nx - 1)
    vy = sum((v - my) ** 2 for v in y) / (ny - 1)
    se2 = vx / nx + vy / ny
    if se2 == 0.0:
        return None
    t = (mx - my) / math.sqrt(se2)
    df = se2 ** 2 / ((vx / nx) ** 2 / (nx - 1) + (vy / ny) ** 2 / (ny - 1))
    return betainc(df / 2.0, 0.5, df / (df + t * t))


def success(path, checkpoint=None):
    """Success of the env1-invisible subject of an eval report (the one of `checkpoint`)."""
    with open(path) as f:
        report = json.load(f)
    for s in report["subjects"]:
        if checkpoint is None or s.get("checkpoint") == checkpoint:
            return s["settings"][0]["success"]
    sys.exit(f"{path}: no subject {checkpoint}")


def shipped(method, seed, crowd):
    path = os.path.join(HERE, "robustness", crowd, "env1-invisible", "eval.json")
    return success(path, f"models/{method}-env1-invisible-s{seed}.fsrlm")


def trained(run, seed, crowd):
    return success(os.path.join(HERE, f"{run}-s{seed}", "robustness", crowd, "env1-invisible", "eval.json"))


def planned(seed, crowd):
    people = crowd.split("-")[-1]
    path = os.path.join(HERE, "c3-plan-on-c1", f"s{seed}-{people}-orca", "eval.json")
    return success(path) if crowd.startswith("orca") and os.path.exists(path) else None


ARMS = [
    ("shipped FSRL (10 ORCA)", lambda s, c: shipped("fsrl", s, c)),
    ("shipped fsrl-plan (10 ORCA)", lambda s, c: shipped("fsrl-plan", s, c)),
    ("C1: FSRL, 5-20 mixed", lambda s, c: trained("c1-any-crowd", s, c)),
    ("C3 P-arm: C1's weights + lookahead", planned),
    ("C3 T-arm: fsrl-plan, 5-20 mixed", lambda s, c: trained("c3-fsrl-plan-any-crowd", s, c)),
]
REFERENCE = {"C1: FSRL, 5-20 mixed": "shipped FSRL (10 ORCA)",
             "C3 P-arm: C1's weights + lookahead": "C1: FSRL, 5-20 mixed",
             "C3 T-arm: fsrl-plan, 5-20 mixed": "C1: FSRL, 5-20 mixed"}


def main():
    values = {}
    for name, get in ARMS:
        for crowd in CROWDS:
            try:
                v = [get(s, crowd) for s in (0, 1, 2)]
            except (FileNotFoundError, SystemExit) as e:
                print(f"<!-- {name}, {crowd}: {e} -->")
                continue
            if None not in v:
                values[(name, crowd)] = v
    print("| env1-invisible, 500 test episodes per seed | " + " | ".join(LABEL[c] for c in CROWDS) + " |")
    print("|---|" + "---|" * len(CROWDS))
    for name, _ in ARMS:
        cells = []
        for crowd in CROWDS:
            v = values.get((name, crowd))
            if v is None:
                cells.append("–")
                continue
            m = sum(v) / 3
            sd = math.sqrt(sum((x - m) ** 2 for x in v) / 2)
            cell = f"**{m:.3f}** ± {sd:.3f} ({' / '.join(f'{x:.3f}' for x in v)})"
            ref = REFERENCE.get(name)
            if ref and (ref, crowd) in values:
                p = welch_p(v, values[(ref, crowd)])
                d = m - sum(values[(ref, crowd)]) / 3
                cell += f", {d:+.3f} vs {ref.split(':')[0].split(' (')[0]}" + (f" (p = {p:.3f})" if p is not None else "")
            cells.append(cell)
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()

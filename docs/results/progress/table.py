#!/usr/bin/env python3
"""Experiment 31's table (docs/REPRODUCTION.md): the shipped fsrl-plan models deciding with the
progress tie-break, mean over seeds 0-2 per setting and arm, Welch against δ = 0, and issue 54
item 4's test (success >= 0.99, Nav. Time and Disc. at or under the paper's FSRL) on the
unseen seeds. Standard library only. Run from the repository root."""
import json
import math
import os
import statistics as st
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "crowds"))
from seeds import welch_p  # noqa: E402  (the Welch test of Experiments C1 and C3)

SETTINGS = ["env1-invisible", "env2-invisible", "env3-invisible",
            "env1-visible", "env2-visible", "env3-visible"]
PAPER = {  # the paper's FSRL row (SPEC.md §8): Nav. Time (s), Disc.
    "env1-invisible": (10.90, 0.01), "env2-invisible": (10.92, 0.07),
    "env3-invisible": (11.69, 0.04), "env1-visible": (11.08, 0.06),
    "env2-visible": (10.32, 0.08), "env3-visible": (11.60, 0.07),
}
ROOT = "docs/results/progress"
# The shipped reports on the test seeds (the δ = 0 arm there; docs/results/fsrl-plan/compare-six).
SHIPPED = {s: (f"docs/results/fsrl-plan/{s}/best-return/fsrl-plan-{s}-s{{k}}/eval.json"
               if s.endswith("invisible") else
               f"docs/results/fsrl-plan/{s}/evals/fsrl-plan-{s}-s{{k}}.json") for s in SETTINGS}
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 8: 2.306, 10: 2.228}


def row(path, setting):
    with open(path) as f:
        d = json.load(f)
    for r in d["subjects"][0]["settings"]:
        if r["setting"] == setting:
            return r
    raise SystemExit(f"{path}: no {setting}")


def arm(seeds, setting, pattern):
    paths = [pattern.format(k=k) for k in seeds]
    if not all(os.path.exists(p) for p in paths):
        return None
    return [row(p, setting) for p in paths]


def p_of(a, b):
    """Welch's two-sided p over seeds (docs/results/crowds/seeds.py's), printed; "–" when
    neither arm has any spread."""
    p = welch_p(a, b)
    return "–" if p is None else f"{p:.3f}"


def fmt(values, digits):
    m = st.mean(values)
    half = T975[len(values) - 1] * st.stdev(values) / math.sqrt(len(values))
    return f"{m:.{digits}f} [{m - half:.{digits}f}, {m + half:.{digits}f}]"


def table(title, arms, seeds):
    print(f"## {title}\n")
    print("| setting | δ | Succ. | Coll. | Nav. Time (s) | Disc. | ΔNav. vs δ=0 (p) | ΔDisc. (p) | item 4 |")
    print("|---|---|---|---|---|---|---|---|---|")
    for s in SETTINGS:
        base = None
        for name, pattern in arms:
            rows = arm(seeds, s, pattern(s))
            if rows is None:
                continue
            succ = [r["success"] for r in rows]
            coll = [r["collision"] for r in rows]
            nav = [r["nav_time_s"] for r in rows]
            disc = [r["disc"] for r in rows]
            if base is None:
                base = (nav, disc)
                dn = dd = "–"
            else:
                dn = f"{st.mean(nav) - st.mean(base[0]):+.2f} ({p_of(nav, base[0])})"
                dd = f"{st.mean(disc) - st.mean(base[1]):+.3f} ({p_of(disc, base[1])})"
            pn, pd = PAPER[s]
            ok = st.mean(succ) >= 0.99 and st.mean(nav) <= pn and st.mean(disc) <= pd
            why = [w for w, bad in [(f"Nav. {st.mean(nav) - pn:+.2f} s", st.mean(nav) > pn),
                                    (f"Disc. {st.mean(disc):.3f} > {pd}", st.mean(disc) > pd),
                                    (f"Succ. {st.mean(succ):.3f}", st.mean(succ) < 0.99)] if bad]
            verdict = "**pass**" if ok else "no: " + ", ".join(why)
            print(f"| {s} | {name} | {fmt(succ, 3)} | {st.mean(coll):.3f} | {fmt(nav, 2)} "
                  f"| {fmt(disc, 3)} | {dn} | {dd} | {verdict} |")
    print()


def main():
    seeds = [0, 1, 2]
    test = [("0 (shipped)", lambda s: SHIPPED[s])] + [
        (d, lambda s, d=d: f"{ROOT}/test/d{d}/fsrl-plan-{s}-s{{k}}/eval.json")
        for d in ["0.01", "0.03"]]
    unseen = [(d, lambda s, d=d: f"{ROOT}/unseen/d{d}/fsrl-plan-{s}-s{{k}}/eval.json")
              for d in ["0", "0.01", "0.03"]]
    print("Per setting, the mean over seeds 0-2 [95 % t interval over seeds]; Welch over seeds "
          "against δ = 0; item 4: success ≥ 0.99, Nav. Time and Disc. ≤ the paper's FSRL.\n")
    table("Test seeds 1000-1499 (500 episodes)", test, seeds)
    table("Unseen seeds 20000-20599 (600 episodes)", unseen, seeds)


if __name__ == "__main__":
    main()

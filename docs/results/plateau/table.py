"""Experiment 17's table from the harness's files: one row per run, then per arm the time to
the plateau over the seeds and its ratio to the fixed arm of the same seed.

    python3 docs/results/plateau/table.py
"""
import json
import math
import pathlib

here = pathlib.Path(__file__).parent
arms = ["fixed-4", "adaptive-4", "adaptive-2", "adaptive-1"]
runs = {}
for p in sorted(here.glob("*-s*.json")):
    d = json.loads(p.read_text())
    runs[(d["config"], d["seed"])] = d
seeds = sorted({s for _, s in runs})

print("| arm | seed | RL episodes/s | updates/s | updates per episode | time to the plateau (s) | x fixed | RL episodes then |")
print("|---|---|---|---|---|---|---|---|")
for arm in arms:
    for s in seeds:
        d = runs.get((arm, s))
        if d is None:
            continue
        f = runs.get(("fixed-4", s), {})
        fixed = f.get("plateau_s")
        t = d.get("plateau_s")
        # A censored fixed arm bounds the ratio from above (it had not got there by its cap).
        ratio = (f"{t / fixed:.2f}" if t and fixed
                 else f"< {t / f['cap_s']:.2f}" if t and f else "–")
        print(f"| {arm} | {s} | {d['episodes_per_s']:.2f} | {d['updates_per_s']:.1f} | "
              f"{d['updates_per_episode']:.1f} | {t:.0f} | {ratio} | {d.get('plateau_episode', '–')} |"
              if t else f"| {arm} | {s} | {d['episodes_per_s']:.2f} | {d['updates_per_s']:.1f} | "
              f"{d['updates_per_episode']:.1f} | censored (> {d['cap_s']:.0f}) | – | – |")


def mean_sd(xs):
    m = sum(xs) / len(xs)
    sd = math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1)) if len(xs) > 1 else 0.0
    return m, sd


print()
print("Time: over the seeds in which the arm reached the plateau; x fixed: over the seeds in which")
print("both it and the fixed arm did (a censored run is left out of both).")
print()
print("| arm | seeds | time to the plateau, mean ± sd (s) | seeds | x fixed, mean ± sd (per seed) |")
print("|---|---|---|---|---|")
for arm in arms:
    ts, rs = [], []
    for s in seeds:
        d = runs.get((arm, s))
        f = runs.get(("fixed-4", s))
        if d and d.get("plateau_s"):
            ts.append(d["plateau_s"])
            if f and f.get("plateau_s"):
                rs.append(d["plateau_s"] / f["plateau_s"])
    if ts:
        m, sd = mean_sd(ts)
        rm, rsd = mean_sd(rs) if rs else (float("nan"), 0.0)
        print(f"| {arm} | {len(ts)} | {m:.0f} ± {sd:.0f} | {len(rs)} | {rm:.2f} ± {rsd:.2f} |")

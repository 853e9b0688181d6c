#!/usr/bin/env python3
"""Experiment 21: paired per-seed differences (arm − shipped) and a paired t over the three seeds.
`python3 docs/results/planning/paired.py k3 k8 [--all]` from the repository root."""
import json,statistics as st,math,sys
def get(p): return json.load(open(p))["subjects"][0]["settings"][0]
def paired(arm, setting):
    rows=[]
    for m in ["success","collision","timeout","nav_time_s","disc"]:
        d=[]
        for s in range(3):
            a=get(f"docs/results/planning/{arm}/fsrl-{setting}-s{s}/eval.json")[m]
            b=get(f"docs/results/grid/fsrl-{setting}-s{s}.json")[m]
            d.append(a-b)
        mu=st.mean(d); sd=st.stdev(d)
        t=mu/(sd/math.sqrt(3)) if sd>0 else float('inf')
        p=1-abs(t)/math.sqrt(2+t*t) if sd>0 else 0.0
        rows.append((m," / ".join(f"{x:+.3f}" for x in d),mu,t,p))
    return rows
SIX=["env1-invisible","env2-invisible","env3-invisible","env1-visible","env2-visible","env3-visible"]
settings=SIX if "--all" in sys.argv else ["env1-invisible"]
for arm in [a for a in sys.argv[1:] if not a.startswith("--")]:
    for setting in settings:
        print(arm,setting)
        for r in paired(arm,setting): print("  %-11s %s  mean %+.3f  t %.2f  p %.3f"%r)

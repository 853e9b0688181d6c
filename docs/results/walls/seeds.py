#!/usr/bin/env python3
"""The walled settings over their seeds (docs/WALLS.md): per setting, each seed's success and the
mean over seeds with its 95 % t interval, wall and people collisions, frozen rate, Nav. Time and
Disc., from docs/results/walls/fsrl-SETTING-sN/report.json. Standard library only; run from the
repository root."""
import glob
import json
import math
import re
import statistics as st

T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776}
SETTINGS = ["corridor", "doorway", "room-invisible", "room-visible",
            "pillars-invisible", "pillars-visible"]


def main():
    print("| setting | seeds | success per seed | Succ. mean [95 %] | wall coll. | people coll. "
          "| frozen | Nav. Time (s) | Disc. |")
    print("|---|---|---|---|---|---|---|---|---|")
    for setting in SETTINGS:
        rows = []
        for path in sorted(glob.glob(f"docs/results/walls/fsrl-{setting}-s*/report.json")):
            seed = int(re.search(r"-s(\d+)/report.json$", path).group(1))
            with open(path) as f:
                r = [x for x in json.load(f)["settings"] if x["setting"] == setting][0]
            rows.append((seed, r))
        if not rows:
            continue
        succ = [r["success"] for _, r in rows]
        mean = st.mean(succ)
        ci = ""
        if len(succ) > 1:
            half = T975[len(succ) - 1] * st.stdev(succ) / math.sqrt(len(succ))
            ci = f" [{mean - half:.3f}, {mean + half:.3f}]"
        m = lambda k: st.mean(r.get(k, 0.0) or 0.0 for _, r in rows)
        print(f"| {setting} | {','.join(str(s) for s, _ in rows)} "
              f"| {' / '.join(f'{x:.3f}' for x in succ)} | **{mean:.3f}**{ci} "
              f"| {m('wall_collision'):.3f} | {m('people_collision'):.3f} | {m('frozen_robot'):.3f} "
              f"| {m('nav_time_s'):.2f} | {m('disc'):.3f} |")


if __name__ == "__main__":
    main()

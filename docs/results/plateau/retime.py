"""Re-times the runs of Experiment 17 that the harness analysed before its fix of 2026-12-05.

Until then `benches/plateau.rs` timed a validated snapshot by the learner's clock at the RL
episode the evaluator named, and the evaluator named it by `policy version - imitation epochs`:
right in the fixed schedule (one version per RL episode), wrong in the adaptive mode (one version
per round of updates). The snapshots, their validation and test scores and the order in which
they were tested do not change; only the time and the episode count of each do:

- time: the evaluator's clock when it took the weights (`wall_s` of its validation line), as the
  harness now records it;
- RL episodes: from the learner's log (`metrics.jsonl`): the episodes it had taken in when it
  published the validated version (the last RL line whose `policy_version` is at most it).

Usage: python3 retime.py RUNS_DIR  (RUNS_DIR: the harness's `target/plateau-work/runs`).
Writes `<run>.validation.jsonl` beside each re-timed `<run>.json` and marks the JSON
`"retimed": true`; files already re-timed or written by the fixed harness are left alone.
"""

import json
import pathlib
import sys


def main(runs_dir: pathlib.Path) -> None:
    here = pathlib.Path(__file__).resolve().parent
    for result_path in sorted(here.glob("*.json")):
        result = json.loads(result_path.read_text())
        name = result_path.stem
        if result.get("retimed") or (here / f"{name}.validation.jsonl").exists():
            continue
        run = runs_dir / name
        log_text = (run / "evaluator" / "validation.jsonl").read_text()
        log = [json.loads(line) for line in log_text.splitlines() if line.strip()]
        # The learner's RL lines: (policy version after the episode, episodes taken in).
        rl = [
            (line["policy_version"], line["episode"] + 1)
            for line in map(json.loads, (run / "metrics.jsonl").read_text().splitlines())
            if line.get("phase") == "rl"
        ]
        assert len(log) == len(result["validations"]), name
        plateau = None
        for v, line in zip(result["validations"], log):
            assert v["episode"] == line["episode"] and v["success"] == line["success_rate"], name
            version = line["policy_version"]
            taken = [episodes for (pv, episodes) in rl if pv <= version]
            v["labelled"] = v["episode"]
            v["episode"] = max(taken) if taken else 0
            v["at_s"] = line["wall_s"]
            if result["plateau_episode"] is not None and v["labelled"] == result["plateau_episode"]:
                plateau = v
        if plateau is not None:
            result["plateau_s"] = plateau["at_s"]
            result["plateau_episode"] = plateau["episode"]
        result["retimed"] = True
        (here / f"{name}.validation.jsonl").write_text(log_text)
        result_path.write_text(json.dumps(result, indent=2) + "\n")
        print(f"{name}: plateau at {result['plateau_s']} s, RL episode {result['plateau_episode']}")


if __name__ == "__main__":
    main(pathlib.Path(sys.argv[1]))

#!/usr/bin/env bash
# Experiment 18 (docs/REPRODUCTION.md): the adaptive replay ratio in a local `fsrl train`, FSRL on
# env1-invisible, seeds 0-2, against the shipped single-process models on the 500 test seeds.
# Copies each run's test evaluation, run.json (time split, realised replay ratio, policy lag,
# waiting) and validation log here, then compares with `fsrl compare --vs` (Welch per metric).
#   docs/results/adaptive-local/run.sh /path/to/fsrl      (RUNS=runs/h18 by default)
set -euo pipefail
cd "$(dirname "$0")/../../.."
fsrl=${1:?usage: $0 /path/to/fsrl}
runs=${RUNS:-runs/h18}
out=docs/results/adaptive-local
mkdir -p "$out/evals" "$out/runs"
for s in 0 1 2; do
  name="fsrl-env1-invisible-s$s"
  cp "$runs/eval/$name/eval.json" "$out/evals/$name.json"
  cp "$runs/$name/run.json" "$out/runs/$name.run.json"
  cp "$runs/$name/validation.jsonl" "$out/runs/$name.validation.jsonl"
done
"$fsrl" compare "$out"/evals/fsrl-env1-invisible-s{0,1,2}.json \
  --vs docs/results/grid/fsrl-env1-invisible-s{0,1,2}.json --out "$out/fsrl" > /dev/null
echo "$out/fsrl/compare.md"
python3 - "$out" <<'PY'
import json, sys
out = sys.argv[1]
keys = ["warm_start_s", "rl_s", "validation_s", "final_evaluation_s", "total_s",
        "learner_updates_per_episode", "learner_policy_lag_mean", "learner_policy_lag_p95",
        "learner_train_s", "learner_wait_s", "actors_sim_s", "actors_wait_s"]
print("| seed | " + " | ".join(keys) + " |")
print("|---" * (len(keys) + 1) + "|")
for s in range(3):
    r = json.load(open(f"{out}/runs/fsrl-env1-invisible-s{s}.run.json"))
    print(f"| {s} | " + " | ".join(f"{r.get(k, float('nan')):.2f}" if isinstance(r.get(k), (int, float)) else "–" for k in keys) + " |")
PY

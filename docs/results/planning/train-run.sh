#!/usr/bin/env bash
# Experiment 22 (docs/REPRODUCTION.md): FSRL trained with planning (top-k 3) by the default
# distributed command, env1-invisible, seeds 0-2. Copies each run's test evaluation, run.json and
# validation log here, then compares with `fsrl compare --vs` (Welch per metric) against the
# shipped models (k0, docs/results/grid) and the shipped models planned at test time (k3).
#   docs/results/planning/train-run.sh /path/to/fsrl      (RUNS=runs/h22b by default)
set -euo pipefail
cd "$(dirname "$0")/../../.."
fsrl=${1:?usage: $0 /path/to/fsrl}
runs=${RUNS:-runs/h22b}
out=docs/results/planning/${ARM:-train-k3}
mkdir -p "$out/evals" "$out/runs"
for s in 0 1 2; do
  name="fsrl-env1-invisible-s$s"
  cp "$runs/eval/$name/eval.json" "$out/evals/$name.json"
  cp "$runs/$name/run.json" "$out/runs/$name.run.json"
  cp "$runs/$name/validation.jsonl" "$out/runs/$name.validation.jsonl"
done
evals=("$out"/evals/fsrl-env1-invisible-s{0,1,2}.json)
"$fsrl" compare "${evals[@]}" --vs docs/results/grid/fsrl-env1-invisible-s{0,1,2}.json \
  --out "$out/vs-shipped" > /dev/null
"$fsrl" compare "${evals[@]}" --vs docs/results/planning/k3/fsrl-env1-invisible-s{0,1,2}/eval.json \
  --out "$out/vs-shipped-k3" > /dev/null
echo "$out/vs-shipped/compare.md $out/vs-shipped-k3/compare.md"
python3 - "$out" <<'PY'
import json, sys
out = sys.argv[1]
keys = ["warm_start_s", "rl_s", "validation_s", "final_evaluation_s", "total_s",
        "learner_updates_per_episode", "learner_policy_lag_mean", "learner_train_s",
        "learner_wait_s", "actors_sim_s", "actors_wait_s"]
print("| seed | " + " | ".join(keys) + " |")
print("|---" * (len(keys) + 1) + "|")
for s in range(3):
    r = json.load(open(f"{out}/runs/fsrl-env1-invisible-s{s}.run.json"))
    print(f"| {s} | " + " | ".join(f"{r.get(k):.2f}" if isinstance(r.get(k), (int, float)) else "–" for k in keys) + " |")
PY

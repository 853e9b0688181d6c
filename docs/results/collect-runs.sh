#!/usr/bin/env bash
# Collects three seeds' trained runs of one method and setting for docs/REPRODUCTION.md: copies
# each run's test evaluation, run.json (time split, realised replay ratio, policy lag, waiting)
# and validation log into OUT, compares them with `fsrl compare --vs` (Welch per metric) against
# each baseline given, and prints the runs' time table.
#   docs/results/collect-runs.sh FSRL RUNS OUT [NAME=BASELINE_PATTERN ...]
# BASELINE_PATTERN names one evaluation per seed with {name} for <method>-<setting>-s<seed>, e.g.
#   shipped=docs/results/grid/{name}.json   k3=docs/results/planning/k3/{name}/eval.json
# METHOD (fsrl), SETTING (env1-invisible) and SEEDS ("0 1 2") pick the runs; BASE_METHOD (fsrl)
# names the baselines' files.
set -euo pipefail
cd "$(dirname "$0")/../.."
fsrl=${1:?usage: $0 FSRL RUNS OUT [NAME=PATTERN ...]}
runs=${2:?RUNS}
out=${3:?OUT}
shift 3
method=${METHOD:-fsrl}
setting=${SETTING:-env1-invisible}
base=${BASE_METHOD:-fsrl}
read -r -a seeds <<< "${SEEDS:-0 1 2}"
mkdir -p "$out/evals" "$out/runs"
evals=()
for s in "${seeds[@]}"; do
  name="$method-$setting-s$s"
  cp "$runs/eval/$name/eval.json" "$out/evals/$name.json"
  cp "$runs/$name/run.json" "$out/runs/$name.run.json"
  cp "$runs/$name/validation.jsonl" "$out/runs/$name.validation.jsonl"
  evals+=("$out/evals/$name.json")
done
for arg in "$@"; do
  label=${arg%%=*}
  pattern=${arg#*=}
  vs=()
  for s in "${seeds[@]}"; do vs+=("${pattern//\{name\}/$base-$setting-s$s}"); done
  "$fsrl" compare "${evals[@]}" --vs "${vs[@]}" --out "$out/vs-$label" > /dev/null
  echo "$out/vs-$label/compare.md"
done
python3 - "$out" "$method-$setting" "${seeds[@]}" <<'PY'
import json, sys
out, stem, seeds = sys.argv[1], sys.argv[2], sys.argv[3:]
keys = ["warm_start_s", "rl_s", "validation_s", "final_evaluation_s", "total_s",
        "learner_updates_per_episode", "learner_policy_lag_mean", "learner_policy_lag_p95",
        "learner_train_s", "learner_wait_s", "actors_sim_s", "actors_wait_s"]
print("| seed | " + " | ".join(keys) + " |")
print("|---" * (len(keys) + 1) + "|")
for s in seeds:
    r = json.load(open(f"{out}/runs/{stem}-s{s}.run.json"))
    print(f"| {s} | " + " | ".join(f"{r[k]:.2f}" if isinstance(r.get(k), (int, float)) else "–" for k in keys) + " |")
PY

#!/usr/bin/env bash
# Experiment 13, H13c (docs/REPRODUCTION.md): the snapshots `fsrl plot frontier` draws for one
# setting, scored on the test seeds instead of the validation seeds, and the same comparison made
# from those scores.
#   docs/results/frontier/test-seeds.sh FSRL_BINARY SETTING [EPISODES]
# Needs the runs' validation snapshots (runs/grid10/<run>/checkpoints/validation/, written by
# `fsrl reproduce`; not committed). Which snapshots take part is decided from the committed
# validation lines alone (docs/results/frontier/logs/: after the ε decay, validation success
# >= 0.95, as `low-disc` and `plot frontier` do; `fsrl plot frontier --list` names them). Each snapshot is evaluated on EPISODES test
# seeds from 1000 (default 500); its scores are written as a validation-style line into
# docs/results/frontier/test-<SETTING>/logs/<run>/metrics.jsonl beside the run's config.toml,
# and `fsrl plot frontier --min-success 0` draws and compares them all (the set is fixed by the
# validation lines; test-<SETTING>/frontier.{md,png,svg}).
set -euo pipefail
cd "$(dirname "$0")/../../.."
FSRL=${1:?usage: test-seeds.sh FSRL_BINARY SETTING [EPISODES]}
SETTING=${2:?usage: test-seeds.sh FSRL_BINARY SETTING [EPISODES]}
EPISODES=${3:-500}
RUNS=${RUNS:-runs/grid10}
OUT=docs/results/frontier/test-$SETTING
mkdir -p "$OUT/logs"
for log in docs/results/frontier/logs/{fsrl,sarl}-"$SETTING"-s[0-9]; do
  run=$(basename "$log")
  mkdir -p "$OUT/logs/$run"
  # The run's own choice was made on validation seeds: here no rule picks among test scores.
  sed 's/^select = .*/select = "last"/' "$log/config.toml" > "$OUT/logs/$run/config.toml"
  # The snapshots that take part, from the validation lines and the run's ε decay.
  episodes=$("$FSRL" plot frontier "$log" --list | cut -f2)
  : > "$OUT/logs/$run/metrics.jsonl"
  for ep in $episodes; do
    snap=$(printf '%s/%s/checkpoints/validation/ep-%06d.fsrlm' "$RUNS" "$run" "$ep")
    dir=$RUNS/test-seeds/$run/ep-$ep
    if [ ! -f "$dir/eval.json" ]; then
      "$FSRL" eval "$snap" --settings "$SETTING" --episodes "$EPISODES" --out "$dir" > /dev/null
    fi
    python3 - "$dir/eval.json" "$ep" >> "$OUT/logs/$run/metrics.jsonl" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))["subjects"][0]["settings"][0]
print(json.dumps({"phase": "validation", "episode": int(sys.argv[2]), "episodes": r["episodes"],
                  "seed_start": 1000, "success_rate": r["success"], "collision_rate": r["collision"],
                  "timeout_rate": r["timeout"], "discomfort": r["disc"], "nav_time_s": r["nav_time_s"]}))
EOF
    echo "$run ep $ep: $(tail -1 "$OUT/logs/$run/metrics.jsonl")" >&2
  done
done
"$FSRL" plot frontier "$OUT"/logs/*-s[0-9] --min-success 0 \
  --title "$SETTING: the validated snapshots scored on $EPISODES test seeds" --out "$OUT/frontier"

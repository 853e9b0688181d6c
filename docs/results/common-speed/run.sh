#!/usr/bin/env bash
# Experiment 15, H15d (docs/REPRODUCTION.md): FSRL and SARL shipped at a speed chosen for both.
#   docs/results/common-speed/run.sh FSRL_BINARY [SETTING...]
# For each setting (default: all six), `fsrl plot frontier --pick common-speed` picks one
# validation snapshot per run from the committed validation logs (docs/results/frontier/logs/):
# the gentlest good one no slower than the median validation Nav. Time of all six runs there.
# Each pick is scored on the 500 test seeds of its setting; the snapshot files are looked up in
# the run roots of $RUNS (not committed; default "runs/grid10 runs/h14e runs/h15"), an earlier
# score of the same snapshot (runs/grid10/test-seeds, H13c) is reused. Writes
# $OUT/{picks.tsv,<run>.json,<run>.md} and per setting vs-<setting>/ (`fsrl compare` FSRL against
# SARL), and compare/ (every setting, beside the paper); OUT defaults to docs/results/common-speed.
# $LOGS: the directories holding the validation logs (space-separated; default
# docs/results/frontier/logs); H15e adds docs/results/frontier/logs-h15e with OUT elsewhere.
set -euo pipefail
cd "$(dirname "$0")/../../.."
FSRL=${1:?usage: run.sh FSRL_BINARY [SETTING...]}
shift
SETTINGS=("$@")
[ ${#SETTINGS[@]} -gt 0 ] || SETTINGS=(env1-invisible env2-invisible env3-invisible env1-visible env2-visible env3-visible)
read -r -a ROOTS <<< "${RUNS:-runs/grid10 runs/h14e runs/h15}"
OUT=${OUT:-docs/results/common-speed}
read -r -a LOGDIRS <<< "${LOGS:-docs/results/frontier/logs}"
mkdir -p "$OUT"
for setting in "${SETTINGS[@]}"; do
  logs=()
  for d in "${LOGDIRS[@]}"; do
    for r in "$d"/{fsrl,sarl}-"$setting"-s[0-9]; do [ -d "$r" ] && logs+=("$r"); done
  done
  "$FSRL" plot frontier "${logs[@]}" --pick common-speed > "$OUT/picks-$setting.tsv"
  while IFS=$'\t' read -r log ep tstar how; do
    run=$(basename "$log")
    [ "$ep" != last ] || { echo "$run: no good snapshot; not covered by this script" >&2; exit 1; }
    snap=
    for root in "${ROOTS[@]}"; do
      f=$(printf '%s/%s/checkpoints/validation/ep-%06d.fsrlm' "$root" "$run" "$ep")
      [ -f "$f" ] && { snap=$f; root_of=$root; break; }
    done
    [ -n "$snap" ] || { echo "$run ep $ep: snapshot not found under ${ROOTS[*]}" >&2; exit 1; }
    dir=$root_of/test-seeds/$run/ep-$ep
    if [ ! -f "$dir/eval.json" ]; then
      nice "$FSRL" eval "$snap" --settings "$setting" --episodes 500 --out "$dir" > /dev/null
    fi
    cp "$dir/eval.json" "$OUT/$run.json"
    cp "$dir/eval.md" "$OUT/$run.md"
    echo "$run: ep $ep ($how, T* = $tstar s) scored" >&2
  done < "$OUT/picks-$setting.tsv"
  "$FSRL" compare "$OUT"/fsrl-"$setting"-s[0-9].json --vs "$OUT"/sarl-"$setting"-s[0-9].json --out "$OUT/vs-$setting" > /dev/null
done
cat "$OUT"/picks-*.tsv > "$OUT/picks.tsv"
"$FSRL" compare "$OUT"/*-s[0-9].json --out "$OUT/compare" > /dev/null
echo "written: $OUT/picks.tsv, $OUT/<run>.json, $OUT/vs-<setting>/, $OUT/compare/" >&2

#!/usr/bin/env bash
# Regenerates the README's pictures with the project itself: four methods trained on
# env1-invisible with the reduced schedule of docs/pictures.toml (about 40 minutes on 2 cores),
# evaluated with ORCA on all six settings, then plotted.
#   docs/make-pictures.sh [FSRL_BINARY]
set -euo pipefail
cd "$(dirname "$0")/.."
FSRL=${1:-target/release/fsrl}
RUNS=${RUNS:-runs/pictures}
OUT=docs/pictures
EPISODES=${EPISODES:-200}
mkdir -p "$RUNS" "$OUT"
for m in sarl sarl+foresight sarl+efficiency fsrl; do
  d="$RUNS/$m"
  if [ ! -f "$d/checkpoints/latest.ckpt" ] || [ ! -f "$d/report.json" ]; then
    rm -rf "$d"
    "$FSRL" train --single-process --config docs/pictures.toml --method "$m" \
      --setting env1-invisible --seed 0 --out "$d"
  fi
done
"$FSRL" eval --orca "$RUNS/sarl" "$RUNS/fsrl" "$RUNS/sarl+foresight" "$RUNS/sarl+efficiency" \
  --episodes "$EPISODES" --out "$RUNS/eval"
"$FSRL" plot bars "$RUNS/eval/eval.json" --out "$OUT/bars"
"$FSRL" plot curves "$RUNS/sarl" "$RUNS/fsrl" --out "$OUT/curves"
"$FSRL" plot ablation "$RUNS/eval/eval.json" --out "$OUT/ablation"
"$FSRL" plot episode "$RUNS/fsrl" --seed 1000 --out "$OUT/episode" --gif-size 300 --stride 2
cp "$RUNS/eval/eval.md" "$OUT/eval.md"
echo "pictures in $OUT"

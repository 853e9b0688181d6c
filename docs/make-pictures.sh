#!/usr/bin/env bash
# Regenerates the README's pictures from the shipped models (models/) and, for the learning
# curves, the runs they came from (runs/reproduce, made by `fsrl reproduce`; docs/REPRODUCTION.md).
# Every model trained on env1-invisible with seed 0 is evaluated with ORCA on all six settings
# (bars.png: how a policy trained in one setting does in the others; kept while its eval.json
# records exactly these models' SHA-256s); every shipped model is evaluated on the setting it
# was trained in (docs/results/grid/<model>.{md,json}, kept while the report's checkpoint_sha256
# is the model file's SHA-256), drawn as the paper's Fig. 5 grid (bars-grid.png) and put in one
# table,
# mean ± std over seeds (docs/results/grid-compare/compare.md); and the ORCA robot's test episode
# in each walled setting (orca-<setting>.{svg,png,gif}, walls drawn).
#   docs/make-pictures.sh [FSRL_BINARY]
set -euo pipefail
cd "$(dirname "$0")/.."
FSRL=${1:-target/release/fsrl}
RUNS=${RUNS:-runs/reproduce}
OUT=docs/pictures
EPISODES=${EPISODES:-500}
mkdir -p "$OUT"
shopt -s nullglob
models=(models/*-env1-invisible-s0.fsrlm)
if [ ${#models[@]} -eq 0 ]; then
  echo "no models/*-env1-invisible-s0.fsrlm: run fsrl reproduce first" >&2
  exit 1
fi
sha256() { sha256sum "$1" | cut -d' ' -f1; }
# An evaluation of $2 in report $1 (eval.json) is current when the report records the file's
# SHA-256 with the episode count asked for.
evaluated() {
  grep -q "\"checkpoint_sha256\": \"$(sha256 "$2")\"" "$1" 2>/dev/null &&
    grep -q "\"episodes_per_setting\": $EPISODES," "$1"
}
six_current=yes
for m in "${models[@]}"; do evaluated "$RUNS/eval-six/eval.json" "$m" || six_current=no; done
# The same models (and no others) and ORCA: kept; otherwise evaluated again.
if [ "$six_current" = yes ] &&
  [ "$(grep -c '"checkpoint_sha256"' "$RUNS/eval-six/eval.json")" -eq ${#models[@]} ] &&
  grep -q '"label": "orca"' "$RUNS/eval-six/eval.json"; then
  echo "$RUNS/eval-six/eval.json is of these models: kept"
else
  "$FSRL" eval --orca "${models[@]}" --episodes "$EPISODES" --out "$RUNS/eval-six"
fi
"$FSRL" plot bars "$RUNS/eval-six/eval.json" --out "$OUT/bars"
curves=("$RUNS"/sarl-env1-invisible-s* "$RUNS"/fsrl-env1-invisible-s*)
if [ ${#curves[@]} -gt 0 ]; then
  curves=("${curves[@]%.log}")
  "$FSRL" plot curves $(printf '%s\n' "${curves[@]}" | sort -u) --out "$OUT/curves"
else
  # A new checkout has the models but not the runs they came from (runs/ is not committed).
  echo "no $RUNS/{sarl,fsrl}-env1-invisible-s* run directories: $OUT/curves* kept as they are" >&2
fi
# The short, the paper and Experiments 8, 9 and 10's schedules (Experiments 7-10): the runs'
# imitation and validation lines are committed in docs/results/paper-schedule/<group>-s<seed>/metrics.jsonl.
# Only the validation pictures are kept (the files hold no per-episode RL lines).
"$FSRL" plot curves docs/results/paper-schedule/*-s[0-9]/ \
  --title "FSRL env1-invisible: five schedules (Experiments 7-10)" --out "$OUT/curves-schedules"
rm -f "$OUT"/curves-schedules.svg "$OUT"/curves-schedules.png
"$FSRL" plot episode models/fsrl-env1-invisible-s0.fsrlm --seed 1000 --out "$OUT/episode" --gif-size 300 --stride 2
# The walled settings (issue 53): the ORCA-driven robot's test episode (seed 1000) in each, its
# walls and obstacles drawn, as orca-<setting>.{svg,png,gif}.
for setting in corridor doorway room-invisible room-visible pillars-invisible pillars-visible; do
  "$FSRL" plot episode --orca --setting "$setting" --seed 1000 --out "$OUT/orca-$setting" \
    --gif-size 300 --stride 3
done
cp "$RUNS/eval-six/eval.md" "$OUT/eval.md"
GRID=docs/results/grid
mkdir -p "$GRID"
for m in models/*.fsrlm; do
  name=$(basename "$m" .fsrlm)
  setting=$(echo "$name" | grep -oE 'env[123]-(in)?visible')
  if ! evaluated "$GRID/$name.json" "$m"; then
    "$FSRL" eval "$m" --settings "$setting" --episodes "$EPISODES" --out "$RUNS/eval-grid/$name"
    cp "$RUNS/eval-grid/$name/eval.json" "$GRID/$name.json"
    cp "$RUNS/eval-grid/$name/eval.md" "$GRID/$name.md"
  fi
done
# The paper's methods (the ablation variants are in ablation.png).
grid=()
for f in "$GRID"/*.json; do
  case "$(basename "$f")" in lstm-rl-*|sarl-env*|fsrl-*) grid+=("$f") ;; esac
done
"$FSRL" plot bars "${grid[@]}" --title "Each method trained and tested in each setting (500 test episodes)" --out "$OUT/bars-grid"
# The reward ablation as the paper's Fig. 8-9: each arm trained in each invisible setting, the
# average over Env 1-3 per seed (Experiment 14; seeds without all three settings are left out).
"$FSRL" plot ablation "$GRID"/*.json \
  --title "Reward ablation: each arm trained in its invisible setting, mean over Env 1-3" \
  --out "$OUT/ablation" || echo "no ablation picture (needs sarl, sarl+foresight, sarl+efficiency and fsrl models)" >&2
# The same reports as one table, mean ± std over the seeds (the README's grid table).
"$FSRL" compare "$GRID"/*.json --out docs/results/grid-compare > /dev/null
echo "pictures in $OUT"

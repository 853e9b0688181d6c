#!/usr/bin/env bash
# Experiment 16 (docs/REPRODUCTION.md): the distributed system's env1-invisible runs against the
# shipped single-process models, on the 500 test seeds. Copies each run's test evaluation,
# run.json (mode, where the time went, replay ratio, policy lag) and validation log here, then
# compares the arms with `fsrl compare --vs` (Welch's test per metric).
#   docs/results/distributed/run.sh /path/to/fsrl      (RUNS=runs/h16 by default)
set -euo pipefail
cd "$(dirname "$0")/../../.."
fsrl=${1:?usage: $0 /path/to/fsrl}
runs=${RUNS:-runs/h16}
out=docs/results/distributed
mkdir -p "$out/evals" "$out/runs"
for m in sarl fsrl; do
  for s in 0 1 2; do
    name="$m-env1-invisible-s$s"
    cp "$runs/eval/$name/eval.json" "$out/evals/$name.json"
    cp "$runs/$name/run.json" "$out/runs/$name.run.json" 2>/dev/null || true
    cp "$runs/$name/validation.jsonl" "$out/runs/$name.validation.jsonl"
  done
  "$fsrl" compare "$out"/evals/$m-env1-invisible-s{0,1,2}.json \
    --vs docs/results/grid/$m-env1-invisible-s{0,1,2}.json --out "$out/$m" > /dev/null
  echo "$out/$m/compare.md"
done

#!/usr/bin/env bash
# Experiment 19 (docs/REPRODUCTION.md): FSRL with value targets on the robot's own choices (and
# n-step returns), env1-invisible, seeds 0-2, single process, against the shipped models on the
# 500 test seeds. Copies each run's test evaluation and validation lines here, compares with
# `fsrl compare --vs` (Welch per metric, over seeds) and scores the runs' last weights too.
#   docs/results/greedy-targets/run.sh /path/to/fsrl ARM      (ARM: a, nstep4, ...; RUNS=runs/h19<arm>;
#   SEEDS="0 1" for the seeds finished so far, default all three)
set -euo pipefail
cd "$(dirname "$0")/../../.."
fsrl=${1:?usage: $0 /path/to/fsrl ARM}
arm=${2:?usage: $0 /path/to/fsrl ARM}
runs=${RUNS:-runs/h19$arm}
out=docs/results/greedy-targets/$arm
mkdir -p "$out/evals" "$out/runs" "$out/last"
seeds=${SEEDS:-0 1 2}
for s in $seeds; do
  name="fsrl-env1-invisible-s$s"
  cp "$runs/eval/$name/eval.json" "$out/evals/$name.json"
  cp "$runs/$name/config.toml" "$out/runs/$name.config.toml"
  grep '"phase":"validation"' "$runs/$name/metrics.jsonl" > "$out/runs/$name.validation.jsonl"
  # Secondary: the run's last weights on the same test seeds.
  if [ ! -f "$out/last/$name.json" ]; then
    "$fsrl" eval "$runs/$name/checkpoints/latest.ckpt" --settings env1-invisible \
      --out "$runs/eval-last/$name" > /dev/null
    cp "$runs/eval-last/$name/eval.json" "$out/last/$name.json"
  fi
done
ours() { for s in $seeds; do echo "$out/$1/fsrl-env1-invisible-s$s.json"; done; }
shipped() { for s in $seeds; do echo "docs/results/grid/fsrl-env1-invisible-s$s.json"; done; }
# shellcheck disable=SC2046
"$fsrl" compare $(ours evals) --vs $(shipped) --out "$out/compare" > /dev/null
# shellcheck disable=SC2046
"$fsrl" compare $(ours last) --vs $(shipped) --out "$out/compare-last" > /dev/null
echo "$out/compare/compare.md $out/compare-last/compare.md"

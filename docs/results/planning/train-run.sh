#!/usr/bin/env bash
# Experiment 22 (docs/REPRODUCTION.md): FSRL trained by the default distributed command, with
# planning (top-k 3, arm B: RUNS=runs/h22b, ARM=train-k3) or without (arm A: RUNS=runs/h22a,
# ARM=default), env1-invisible, seeds 0-2, against the shipped models (k0, docs/results/grid) and
# the shipped models planned at test time (k3) (docs/results/collect-runs.sh).
#   docs/results/planning/train-run.sh /path/to/fsrl
set -euo pipefail
cd "$(dirname "$0")/../../.."
docs/results/collect-runs.sh "${1:?usage: $0 /path/to/fsrl}" "${RUNS:-runs/h22b}" \
  "docs/results/planning/${ARM:-train-k3}" shipped='docs/results/grid/{name}.json' \
  shipped-k3='docs/results/planning/k3/{name}/eval.json'

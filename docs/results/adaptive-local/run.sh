#!/usr/bin/env bash
# Experiment 18 (docs/REPRODUCTION.md): the adaptive replay ratio in a local `fsrl train`, FSRL on
# env1-invisible, seeds 0-2, against the shipped single-process models on the 500 test seeds
# (docs/results/collect-runs.sh; the comparison is in fsrl/compare.md).
#   docs/results/adaptive-local/run.sh /path/to/fsrl      (RUNS=runs/h18 by default)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
"$here/../collect-runs.sh" "${1:?usage: $0 /path/to/fsrl}" "${RUNS:-runs/h18}" \
  docs/results/adaptive-local shipped='docs/results/grid/{name}.json'
# The report's old name: fsrl/ (written before the script was shared).
rm -rf "$here/fsrl" && mv "$here/vs-shipped" "$here/fsrl"

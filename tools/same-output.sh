#!/usr/bin/env bash
# Checks that a refactoring changed no output: runs the analysis and training commands (compare,
# compare --vs, plot bars/ablation/curves/frontier/episode, eval, sim, sim --scenes, reproduce
# --dry-run, a tiny single-process train and export-model) with two fsrl binaries on the
# committed results and models, and compares every file written and every line printed, byte for
# byte, after replacing each run's own directory name and leaving out wall-clock times.
#   tools/same-output.sh OLD_FSRL NEW_FSRL [WORK_DIR]
# Build the old binary from a worktree of the old commit, e.g.
#   git worktree add /tmp/old HEAD~1 && (cd /tmp/old && cargo build --release --workspace)
set -uo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 2 ] || { echo "usage: $0 OLD_FSRL NEW_FSRL [WORK_DIR]" >&2; exit 2; }
old=$(realpath "$1"); new=$(realpath "$2")
work=${3:-$(mktemp -d)}
# CrowdNav's test scenes (testdata/README.md); FSRL_CROWDNAV_OUTCOMES_DIR names another copy, as in
# sim/tests/crowdnav_parity.rs.
scenes=${FSRL_CROWDNAV_OUTCOMES_DIR:-testdata/crowdnav_cases}/test_h10_scenes.csv
[ -f "$scenes" ] || { echo "error: $scenes is missing (CrowdNav's test scenes, testdata/)" >&2; exit 2; }

outputs() {
  local B=$1 O=$2
  rm -rf "$O"; mkdir -p "$O"
  run() { local name=$1; shift; "$B" "$@" >"$O/$name.stdout" 2>"$O/$name.stderr"; echo "exit $?" >>"$O/$name.stdout"; }
  run compare compare docs/results/grid/*.json --out "$O/compare"
  run vs compare docs/results/grid/fsrl-env1-invisible-s*.json --vs docs/results/grid/sarl-env1-invisible-s*.json --out "$O/vs"
  run bars plot bars docs/results/grid/*.json --out "$O/bars"
  run ablation plot ablation docs/results/grid/*.json --out "$O/ablation"
  run curves plot curves docs/results/paper-schedule/*-s[0-9]/ --title t --out "$O/curves"
  run frontier plot frontier docs/results/frontier/logs/fsrl-env2-invisible-s? docs/results/frontier/logs/sarl-env2-invisible-s? --title f --out "$O/frontier"
  run frontier2 plot frontier docs/results/paper-schedule/fsrl-5000x20-s? --method fsrl --setting env1-invisible --decay-end 4000 --out "$O/frontier2"
  run pick plot frontier docs/results/frontier/logs/fsrl-env2-invisible-s? --pick common-speed
  run list plot frontier docs/results/frontier/logs/fsrl-env2-invisible-s? --list
  run episode plot episode models/fsrl-env1-invisible-s0.fsrlm --seed 1000 --out "$O/episode" --gif-size 120 --stride 4
  run episode-orca plot episode --orca --seed 1001 --out "$O/episode-orca" --no-gif
  run eval eval models/fsrl-env1-invisible-s0.fsrlm models/lstm-rl-env1-visible-s0.fsrlm --settings env1-invisible,env3-visible --episodes 12 --out "$O/eval"
  run eval-orca eval --orca --episodes 8 --out "$O/eval-orca"
  run sim sim --episodes 15 --svg "$O/sim.svg"
  run scenes sim --scenes "$scenes" --robot holonomic --semantics crowdnav --episodes 30
  run dry reproduce --dry-run --runs "$O/rr" --models models
  printf '[train]\nvalidation_every_episodes = 3\nvalidation_episodes = 5\nselect = "best-validation"\n' >"$O/tiny.toml"
  # The run directory's name is its run id, which the checkpoint holds: the same in both.
  run train train --single-process --config "$O/tiny.toml" --method sarl --il-episodes 4 --il-epochs 1 --rl-episodes 6 --eval-episodes 10 --out "$O/run/train"
  run export export-model "$O/run/train" --out "$O/train.fsrlm"
  rm -f "$O/run/train/lock" "$O/run/train/run.json" # a pid; wall-clock times
}
outputs "$old" "$work/old"
outputs "$new" "$work/new"
normal() { sed -E "s#$work/(old|new)#DIR#g; s/[0-9.]+ s in all//; s/\"wall_s\":[0-9.e-]+//; s/\([0-9.]+\/s, ETA [0-9]+ s\).*//" "$1"; }
status=0 files=0
while IFS= read -r f; do
  files=$((files + 1))
  if [ ! -f "$work/new/$f" ]; then echo "missing in new: $f"; status=1; continue; fi
  case "$f" in
    *.stdout | *.stderr | *.jsonl | *.toml) cmp -s <(normal "$work/old/$f") <(normal "$work/new/$f") ;;
    *) cmp -s "$work/old/$f" "$work/new/$f" ;;
  esac || { echo "differs: $f"; status=1; }
done < <(cd "$work/old" && find . -type f | sort)
extra=$(comm -13 <(cd "$work/old" && find . -type f | sort) <(cd "$work/new" && find . -type f | sort))
[ -n "$extra" ] && { echo "only in new: $extra"; status=1; }
[ $status -eq 0 ] && echo "same output: $files files byte-identical (paths and wall-clock times left out) in $work"
exit $status

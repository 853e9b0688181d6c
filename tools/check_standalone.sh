#!/usr/bin/env bash
# Checks that the repository stands alone: no tracked file names a directory beside the clone
# (`../shared`, its `data/`, `reference/`, `paper/`, SPEC.md or CONVENTIONS.md) or the
# development machine's `/work/shared`. The reference data the tests replay is in testdata/ and the
# specification in docs/SPEC.md. Prints every offending line as FILE:LINE:TEXT and exits 1.
#   tools/check_standalone.sh
set -euo pipefail
cd "$(dirname "$0")/.."
git rev-parse --is-inside-work-tree >/dev/null 2>&1 || {
  echo "error: $(pwd) is not a git checkout: the check reads the tracked files" >&2
  exit 2
}

pattern='\.\./shared\b|/work/shared\b|\bshared/(data|reference|paper|hooks)\b|\bshared/(SPEC|CONVENTIONS)\.md'
# -I skips binary files (model files); this script names the patterns, so it is left out.
status=0
hits=$(git grep -n -I -E "$pattern" -- . ':(exclude)tools/check_standalone.sh') || status=$?
case $status in
  0)
    echo "error: these tracked files point outside the repository (move the data to testdata/, cite docs/SPEC.md or the upstream project):" >&2
    echo "$hits" >&2
    exit 1
    ;;
  1) echo "standalone: no tracked file names ../shared, shared/data or /work/shared" ;;
  *) echo "error: git grep failed (exit $status)" >&2; exit 2 ;;
esac

#!/usr/bin/env bash
# Free ports for tests and benches come from the dev-only crate `testkit` (testkit::free_port),
# never from `bind(0)`: a port the kernel hands out for `bind(0)` is an ephemeral one, which any
# outgoing connection (another test's zenoh client) may take as its source port between the
# probe and the bind of the process it was meant for (a fresh-clone CI run lost a learner's
# --listen port that way). Fails, naming file and line, if any Rust file outside testkit/ and
# the product code listed below binds a loopback or wildcard address to port 0.
# Usage: tools/check_ports.sh [ROOT]   (ROOT: the repository, by default this script's)
set -euo pipefail
cd "${1:-$(dirname "$0")/..}"

# Product code that binds port 0 for a listener of its own and keeps it (or hands the port to a
# child at once): not test support. A path here must still exist (a stale exception fails).
exceptions=(
  dashboard/src/http.rs # its unit test serves the page on the listener it bound itself
)

addr='(127\.0\.0\.1|localhost|0\.0\.0\.0|\[?::1?\]?)'
patterns=(
  "bind\(\s*\"${addr}:0\""                                                   # bind("127.0.0.1:0")
  "bind\(\s*\(\s*\"${addr}\"\s*,\s*0\s*\)"                                    # bind(("127.0.0.1", 0))
  "bind\(\s*\(\s*(std::net::)?Ipv[46]Addr::(LOCALHOST|UNSPECIFIED)\s*,\s*0\s*\)" # bind((Ipv4Addr::LOCALHOST, 0))
)

for e in "${exceptions[@]}"; do
  [ -f "$e" ] || { echo "tools/check_ports.sh: the exception $e is no file any more: remove it from the list" >&2; exit 1; }
done

files=$(git ls-files -- '*.rs' 2>/dev/null || find . -name '*.rs' -not -path './target/*' | sed 's|^\./||')
bad=0
while IFS= read -r f; do
  case "$f" in
    testkit/* | third_party/* | target/*) continue ;;
  esac
  for e in "${exceptions[@]}"; do
    [ "$f" = "$e" ] && continue 2
  done
  [ -f "$f" ] || continue
  for p in "${patterns[@]}"; do
    if hits=$(grep -nP "$p" "$f"); then
      while IFS= read -r h; do
        echo "$f:$h" >&2
      done <<<"$hits"
      bad=1
    fi
  done
done <<<"$files"

if [ "$bad" -ne 0 ]; then
  echo "error: the lines above take a free port from bind(0); use testkit::free_port() (testkit/src/lib.rs says why)" >&2
  exit 1
fi
echo "tools/check_ports.sh: no bind(0) free-port helper outside testkit/ and the listed product code"

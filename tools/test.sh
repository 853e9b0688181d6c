#!/usr/bin/env bash
# The tests: the one command to run them, here and in CI (.ci/run calls it). On a machine with
# only the Rust toolchain it first provides what the tests need besides cargo:
#   - Python with `msgpack`, `eclipse-zenoh`, `rosbags`, `xxhash` and `tensorboard`
#     (proto/tests/proto/python.rs, serve/tests/interop.rs, tests/distributed.rs,
#     tests/tensorboard.rs and tests/multihost.rs run `python3` from PATH): a project-local
#     virtual environment .venv/, created and filled when needed, put first on PATH;
#   - a headless browser, Debian's `chromium` (tests/dashboard.rs opens `fsrl train
#     --dashboard`'s page in it): installed when missing and running as root with apt-get;
#   - a TrueType font for the pictures (viz/src/fonts.rs): installed when missing and running as
#     root with apt-get, otherwise a message saying how to install one or set FSRL_FONT.
# Then it runs `cargo test --workspace --release ARGS...` and exits with its status. Extra
# arguments go to cargo test as they are; with `-p`/`--package` only those packages are tested
# (cargo would ignore `-p` next to `--workspace`). Tests that need root (tests/multihost.rs,
# network namespaces) print why they skip when not run as root; CI runs as root and requires them.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD

zenoh_version=1.10.2
rosbags_version=0.11.9
xxhash_version=3.5.0
tensorboard_version=2.20.0
venv="$root/.venv"

say() { echo "tools/test.sh: $*" >&2; }
die() {
  say "error: $*"
  exit 1
}
is_root() { [ "$(id -u)" -eq 0 ]; }
# Installs Debian/Ubuntu packages when running as root with apt-get; fails otherwise.
apt_install() {
  if ! is_root || ! command -v apt-get >/dev/null; then return 1; fi
  say "installing $* (apt-get)"
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}

# --- Python: .venv/ with msgpack, eclipse-zenoh, rosbags and xxhash ----------------------------
venv_works() { "$venv/bin/python3" -m pip --version >/dev/null 2>&1; }
if ! venv_works; then
  if ! command -v python3 >/dev/null; then
    apt_install python3 python3-venv ||
      die "python3 is needed for the cross-language tests; install it (Debian/Ubuntu: sudo apt-get install python3 python3-venv)"
  fi
  say "creating the virtual environment .venv/ (Python packages for the cross-language tests)"
  if ! { python3 -m venv "$venv" >/dev/null && venv_works; }; then
    # Debian and Ubuntu ship the venv module (ensurepip) separately.
    if ! { apt_install python3-venv && python3 -m venv "$venv" >/dev/null && venv_works; }; then
      die "python3 -m venv $venv failed; install Python's venv module (Debian/Ubuntu: sudo apt-get install python3-venv) and run again"
    fi
  fi
fi
have_modules() {
  "$venv/bin/python3" - "$zenoh_version" "$rosbags_version" "$xxhash_version" "$tensorboard_version" >/dev/null 2>&1 <<'EOF'
import sys
from importlib.metadata import version
import msgpack, zenoh, rosbags, xxhash
from tensorboard.backend.event_processing import event_accumulator
sys.exit(version("eclipse-zenoh") != sys.argv[1] or version("rosbags") != sys.argv[2]
         or version("xxhash") != sys.argv[3] or version("tensorboard") != sys.argv[4])
EOF
}
if ! have_modules; then
  wanted="msgpack, eclipse-zenoh==$zenoh_version, rosbags==$rosbags_version, xxhash==$xxhash_version and tensorboard==$tensorboard_version"
  say "installing $wanted into .venv/ (pip)"
  "$venv/bin/python3" -m pip install --quiet --disable-pip-version-check \
    msgpack "eclipse-zenoh==$zenoh_version" "rosbags==$rosbags_version" "xxhash==$xxhash_version" \
    "tensorboard==$tensorboard_version" ||
    die "pip could not install $wanted into .venv/ (network?)"
  have_modules || die "$wanted: still not all importable from .venv/"
fi
export VIRTUAL_ENV="$venv"
export PATH="$venv/bin:$PATH"
unset PYTHONHOME

# --- a TrueType font for the pictures -------------------------------------------------------
# The candidates viz/src/fonts.rs tries (CANDIDATES) when FSRL_FONT is unset; keep them in step.
fonts=(
  /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf
  /usr/share/fonts/TTF/DejaVuSans.ttf
  /usr/share/fonts/dejavu/DejaVuSans.ttf
  /usr/share/fonts/dejavu-sans-fonts/DejaVuSans.ttf
  /usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf
  /usr/share/fonts/liberation-sans/LiberationSans-Regular.ttf
  /System/Library/Fonts/Supplemental/Arial.ttf
)
have_font() {
  local f
  for f in "${fonts[@]}"; do [ -f "$f" ] && return 0; done
  return 1
}
if [ -n "${FSRL_FONT:-}" ]; then
  [ -f "$FSRL_FONT" ] || die "FSRL_FONT=$FSRL_FONT is not a file (it names the .ttf font the pictures are drawn with)"
elif ! have_font && ! { apt_install fonts-dejavu-core && have_font; }; then
  die "the pictures' tests need a TrueType font and none was found (viz/src/fonts.rs looks for ${fonts[0]} and similar).
  Install one:  sudo apt-get install fonts-dejavu-core   (Fedora: sudo dnf install dejavu-sans-fonts; Arch: sudo pacman -S ttf-dejavu)
  or name any .ttf file:  FSRL_FONT=/path/to/font.ttf tools/test.sh"
fi

# --- a headless browser for the dashboard's page ---------------------------------------------
# tests/dashboard.rs runs `chromium` (or FSRL_CHROMIUM) from PATH.
if [ -n "${FSRL_CHROMIUM:-}" ]; then
  [ -x "$FSRL_CHROMIUM" ] || die "FSRL_CHROMIUM=$FSRL_CHROMIUM is not an executable (the headless browser tests/dashboard.rs runs)"
elif ! command -v chromium >/dev/null && ! apt_install --no-install-recommends chromium; then
  die "tests/dashboard.rs needs a headless Chromium and none was found.
  Install it:  sudo apt-get install chromium   (or name one: FSRL_CHROMIUM=/path/to/chrome tools/test.sh)"
fi

# --- the tests ------------------------------------------------------------------------------
scope=(--workspace)
for arg in "$@"; do
  case "$arg" in
    --) break ;;
    -p* | --package | --package=*) scope=() ;;
  esac
done
is_root || say "not root: tests/multihost.rs will skip (it needs network namespaces: root with iproute2, as in CI)"
cmd=(cargo test ${scope[@]+"${scope[@]}"} --release "$@")
say "python3 is $(command -v python3); running: ${cmd[*]}"
exec "${cmd[@]}"

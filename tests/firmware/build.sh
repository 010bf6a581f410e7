#!/usr/bin/env bash
# Builds the real controller firmwares the firmware tests talk to, from the peers folder
# (../shared/peers beside the repository, or $GRBL_PEERS_DIR), into OUT_DIR (default
# target/firmware in the repository):
#   OUT_DIR/grbl11h/grbl/grbl-sim/grbl_sim.exe   GRBL 1.1h with grbl-sim
#   OUT_DIR/grblhal3/build/grblHAL_sim            grblHAL, 3 axes (X Y Z)
#   OUT_DIR/grblhal6/build/grblHAL_sim            grblHAL, 6 axes (X Y Z A B C)
# A firmware whose binary exists is not rebuilt (delete OUT_DIR to rebuild). Builds are
# serialised with a lock file, so concurrent test binaries may call this script.
# Usage: tests/firmware/build.sh [OUT_DIR] [grbl11h|grblhal3|grblhal6 ...]
# Needs gcc, make, python3 (GRBL), cmake (grblHAL), and socat to run them (the tests).
set -eu
repo=$(cd "$(dirname "$0")/../.." && pwd)
if top=$(git -C "$repo" rev-parse --show-toplevel 2>/dev/null); then repo=$top; fi
PEERS=${GRBL_PEERS_DIR:-$repo/../shared/peers}
OUT=${1:-$repo/target/firmware}
shift || true
WHICH=${*:-grbl11h grblhal3 grblhal6}

die() { echo "tests/firmware/build.sh: $*" >&2; exit 1; }
need() {
    command -v "$1" >/dev/null 2>&1 ||
        die "'$1' is missing: install it (Debian: apt-get install -y $2), or run tests/install-peers.sh"
}
[ -d "$PEERS" ] || die "no firmware peers folder at $PEERS (set GRBL_PEERS_DIR)"
PEERS=$(cd "$PEERS" && pwd)
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

exec 9>"$OUT/.build.lock"
flock 9

build() { # name binary-relative-path script args...
    local name=$1 rel=$2 script=$3; shift 3
    local bin="$OUT/$name/$rel"
    if [ -x "$bin" ]; then echo "$bin"; return; fi
    [ -f "$PEERS/$script" ] || die "missing $PEERS/$script"
    echo "building $name from $PEERS ..." >&2
    bash "$PEERS/$script" "$OUT/$name" "$@" >/dev/null ||
        die "building $name failed (log under $OUT/$name)"
    [ -x "$bin" ] || die "building $name produced no $bin"
    echo "$bin"
}

need socat socat
for fw in $WHICH; do
    case $fw in
    grbl11h)
        need gcc gcc; need make make; need python3 python3
        build grbl11h grbl/grbl-sim/grbl_sim.exe build-grbl-sim.sh ;;
    grblhal3 | grblhal6)
        need gcc gcc; need make make; need cmake cmake
        build "$fw" build/grblHAL_sim build-grblhal-sim.sh "${fw#grblhal}" ;;
    *) die "unknown firmware '$fw' (grbl11h, grblhal3, grblhal6)" ;;
    esac
done

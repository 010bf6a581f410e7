#!/usr/bin/env bash
# Builds the real controller firmwares the firmware tests talk to, from the peers folder
# (../shared/peers beside the repository, or $GRBL_PEERS_DIR), into OUT_DIR (default
# target/firmware in the repository):
#   OUT_DIR/grbl11h/grbl/grbl-sim/grbl_sim.exe   GRBL 1.1h with grbl-sim, its harness
#       given limit switches (grbl-sim-limit-switches.py beside this script; `-l`)
#   OUT_DIR/grblhal3/build/grblHAL_sim            grblHAL, 3 axes (X Y Z)
#   OUT_DIR/grblhal6/build/grblHAL_sim            grblHAL, 6 axes (X Y Z A B C)
# A firmware whose binary exists is not rebuilt (delete OUT_DIR to rebuild); GRBL 1.1h is
# rebuilt when its stamp (OUT_DIR/grbl11h/.harness-patch: the sha256 of the harness patch)
# is not the current patch's. Builds are serialised with a lock file, so concurrent test
# binaries may call this script (the tests call it before every start: it is quick when
# nothing is to be built).
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

# The stamp a build must carry to be current: empty for the peers' builds as they are.
stamp_for() {
    case $1 in
    grbl11h) sha256sum "$repo/tests/firmware/grbl-sim-limit-switches.py" | cut -d' ' -f1 ;;
    *) echo "" ;;
    esac
}

build() { # name binary-relative-path script args...
    local name=$1 rel=$2 script=$3; shift 3
    local bin="$OUT/$name/$rel" want have=""
    want=$(stamp_for "$name")
    [ -f "$OUT/$name/.harness-patch" ] && have=$(cat "$OUT/$name/.harness-patch")
    if [ -x "$bin" ] && [ "$have" = "$want" ]; then echo "$bin"; return; fi
    local tool
    for tool in $TOOLS; do need "$tool" "$tool"; done
    [ -f "$PEERS/$script" ] || die "missing $PEERS/$script"
    echo "building $name from $PEERS ..." >&2
    bash "$PEERS/$script" "$OUT/$name" "$@" >/dev/null ||
        die "building $name failed (log under $OUT/$name)"
    [ -x "$bin" ] || die "building $name produced no $bin"
    if [ "$name" = grbl11h ]; then
        # The harness's limit switches: patch the tree the peer script built, then make
        # it again with the peer script's flags (GRBL's own sources are untouched).
        python3 "$repo/tests/firmware/grbl-sim-limit-switches.py" "$OUT/$name/grbl" ||
            die "patching grbl-sim with limit switches failed"
        (cd "$OUT/$name/grbl/grbl-sim" &&
            make main FLAGS="-g -O3 -fcommon" >>"$OUT/$name/grbl/build.log" 2>&1) ||
            die "building $name with limit switches failed (log: $OUT/$name/grbl/build.log)"
    fi
    [ -z "$want" ] || echo "$want" >"$OUT/$name/.harness-patch"
    echo "$bin"
}

need socat socat
for fw in $WHICH; do
    case $fw in
    grbl11h)
        TOOLS="gcc make python3"
        build grbl11h grbl/grbl-sim/grbl_sim.exe build-grbl-sim.sh ;;
    grblhal3 | grblhal6)
        TOOLS="gcc make cmake"
        build "$fw" build/grblHAL_sim build-grblhal-sim.sh "${fw#grblhal}" ;;
    *) die "unknown firmware '$fw' (grbl11h, grblhal3, grblhal6)" ;;
    esac
done

#!/usr/bin/env bash
# Installs every peer the test suite talks to, so that `cargo test --workspace` runs every
# test on a fresh machine (a test whose peer is missing fails naming this script):
#   system packages (Debian/Ubuntu apt-get): Aravis 0.8 tools and development files,
#     Mosquitto, headless Chromium, Node.js and npm, iproute2 and util-linux (network
#     namespaces), socat, gcc, make and cmake (the real GRBL/grblHAL firmware builds),
#     LinuxCNC 2.9 (linuxcnc-uspace, without its recommends);
#   Python packages (pip, versions tested): pyserial, numpy, paho-mqtt, grpcio-tools,
#     pymodbus, python-can, canopen;
#   npm packages: CNCjs 1.11.5 (tests/interop/cncjs), playwright-core and axe-core
#     (tests/interop/web);
#   the real controller firmware (tests/firmware/build.sh, from ../shared/peers);
#   a vcan0 SocketCAN interface where the kernel has CAN (best effort: a kernel without
#     CAN cannot have one, and the SocketCAN test says so).
# Idempotent: only what is missing is installed, and nothing is printed when everything
# is there. Needs root (or sudo) only when a system package is missing.
# Usage: tests/install-peers.sh   (the README's test command: tests/install-peers.sh && cargo test --workspace)
set -euo pipefail
cd "$(dirname "$0")/.."

say() { echo "tests/install-peers.sh: $*" >&2; }
die() { say "$*"; exit 1; }
as_root() {
  if [ "$(id -u)" = 0 ]; then "$@"
  elif command -v sudo >/dev/null; then sudo "$@"
  else die "needs root to run: $* (run this script as root or install sudo)"; fi
}
# Best effort as root: fails (returns 1) instead of stopping the script.
try_root() {
  if [ "$(id -u)" = 0 ]; then "$@"
  elif command -v sudo >/dev/null; then sudo -n "$@"
  else return 1; fi
}
have() { command -v "$1" >/dev/null 2>&1; }
have_pkg() { have dpkg && dpkg -s "$1" >/dev/null 2>&1; }

# --- system packages -------------------------------------------------------------------
# Each: a check (a command, or a dpkg package for libraries) and the Debian package.
missing=()
need_cmd() { have "$1" || missing+=("$2"); }
need_lib() { have_pkg "$1" || missing+=("$1"); }
# Aravis 0.8 (GigE Vision): its tools discover and stream from our camera emulator, its
# fake camera serves our driver (tests/tests/gige_interop.rs); libaravis-dev for the
# drivers' optional `aravis` feature (its pkg-config file also needs libusb-1.0-0-dev).
need_cmd arv-tool-0.8 aravis-tools-cli
need_cmd arv-camera-test-0.8 aravis-tools
need_cmd pkg-config pkg-config
if ! have pkg-config || ! pkg-config --exists aravis-0.8 glib-2.0 2>/dev/null; then
  missing+=(libaravis-dev libglib2.0-dev libusb-1.0-0-dev)
fi
# iproute2 (`ip`) and util-linux (`unshare`): private network namespaces where the machine
# allows them (tests/src/netns.rs).
need_cmd ip iproute2
need_cmd unshare util-linux
# Mosquitto: the real MQTT broker of tests/tests/northbound.rs.
[ -x /usr/sbin/mosquitto ] || missing+=(mosquitto)
# Headless Chromium and Node.js: the web page's test (tests/tests/service_web.rs) and
# CNCjs (tests/tests/proxy.rs).
[ -x /usr/bin/chromium ] || missing+=(chromium)
need_cmd node nodejs
need_cmd npm npm
# The real firmware: built with gcc, make (GRBL 1.1h + grbl-sim) and cmake (grblHAL),
# run on pseudo-terminals made by socat; flock serialises the builds.
need_cmd gcc gcc
need_cmd make make
need_cmd cmake cmake
need_cmd socat socat
need_cmd flock util-linux
# A C++ compiler: the fuzz targets' libFuzzer wrappers (libfuzzer-sys builds libFuzzer's
# C++; CI checks that they build).
need_cmd g++ g++
# Python 3 and pip for the independent Python peers.
need_cmd python3 python3
if ! python3 -m pip --version >/dev/null 2>&1; then missing+=(python3-pip); fi
if [ ${#missing[@]} -gt 0 ]; then
  # Each package once, in order.
  mapfile -t missing < <(printf '%s\n' "${missing[@]}" | awk '!seen[$0]++')
  have apt-get || die "missing system packages (${missing[*]}) and no apt-get to install them: install them by hand"
  say "installing system packages: ${missing[*]}"
  as_root apt-get update -qq >/dev/null
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
fi

# LinuxCNC 2.9 (linuxcnc-uspace): the real controller of tests/tests/a_real_linuxcnc.rs, started
# headless by ../shared/peers/linuxcnc/start.sh. --no-install-recommends: with its
# recommends it pulls 1.3 GB, an RT kernel image among them (about 200 MB without).
if ! have linuxcnc; then
  have apt-get || die "LinuxCNC (linuxcnc-uspace) is missing and there is no apt-get to install it: install it by hand"
  say "installing LinuxCNC (linuxcnc-uspace, without recommends)"
  as_root apt-get update -qq >/dev/null
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends linuxcnc-uspace >/dev/null
fi

# --- Python packages -------------------------------------------------------------------
# pyserial: the independent GRBL sender (tests/interop/grbl_sender.py); numpy: the
# independent frame renderer (tests/interop/render_board.py); paho-mqtt and grpcio-tools:
# the independent Sparkplug B plant (tests/interop/sparkplug/plant.py); pymodbus: the
# independent Modbus client and server (tests/interop/modbus_*.py); canopen over
# python-can's slcan: the independent CANopen master and node (tests/interop/canopen_*.py).
want_py="pyserial numpy paho-mqtt==2.1.0 grpcio-tools==1.85.1 pymodbus==3.16.1 canopen==2.4.1 python-can==4.6.1 ezdxf==1.4.5 svgelements==1.9.6"
# Only what is missing or at another version than the one tested.
py_missing=$(python3 - $want_py <<'EOF'
import importlib.metadata as m, sys
out = []
for spec in sys.argv[1:]:
    name, _, version = spec.partition("==")
    try:
        have = m.version(name)
    except m.PackageNotFoundError:
        have = None
    if have is None or (version and have != version):
        out.append(spec)
print(" ".join(out))
EOF
)
if [ -n "$py_missing" ]; then
  say "installing Python packages: $py_missing"
  # A Python that refuses pip installs (PEP 668) is told this is meant.
  # shellcheck disable=SC2086
  python3 -m pip install --quiet $py_missing 2>/dev/null ||
    python3 -m pip install --quiet --break-system-packages $py_missing
fi

# --- npm packages ----------------------------------------------------------------------
# CNCjs 1.11.5: a real G-code sender for the live pass-through, driven through its
# socket.io API by tests/interop/cncjs_sender.js (about 45 s to install; its serial
# binding ships prebuilt for linux-x64).
if [ ! -f tests/interop/cncjs/node_modules/cncjs/package.json ]; then
  say "installing CNCjs 1.11.5 (npm)"
  npm install --prefix tests/interop/cncjs cncjs@1.11.5 --omit=dev --no-audit --no-fund --loglevel=error >/dev/null
fi
# playwright-core and axe-core (pinned in tests/interop/web/package.json): drive headless
# Chromium for the web page's test and check each view's accessibility
# (tests/interop/web/drive_page.js).
if [ ! -f tests/interop/web/node_modules/playwright-core/package.json ] ||
  [ ! -f tests/interop/web/node_modules/axe-core/axe.min.js ]; then
  say "installing playwright-core and axe-core (npm)"
  npm install --prefix tests/interop/web --no-package-lock --no-audit --no-fund --loglevel=error >/dev/null
fi

# --- the real controller firmware --------------------------------------------------------
# GRBL 1.1h (grbl-sim) and grblHAL (3 and 6 axes) from ../shared/peers, built once into
# target/firmware (the script rebuilds nothing that is there and prints the binaries).
if [ -f tests/firmware/build.sh ]; then
  bash tests/firmware/build.sh >/dev/null || die "building the real firmware failed (tests/firmware/build.sh, above)"
fi

# --- SocketCAN -------------------------------------------------------------------------
# vcan0 for tests/tests/canopen_socketcan.rs, where the kernel has CAN support and we may
# create interfaces; elsewhere that test says why it cannot run.
if have ip && ! ip link show vcan0 >/dev/null 2>&1; then
  if { [ -d /sys/module/vcan ] || try_root modprobe vcan >/dev/null 2>&1; } &&
    try_root ip link add vcan0 type vcan >/dev/null 2>&1; then
    try_root ip link set vcan0 up
    say "brought up the SocketCAN interface vcan0"
  fi
fi
exit 0

#!/usr/bin/env python3
"""An independent GRBL 1.1 sender, written against GRBL's public interface docs only.

It does what UGS and CNCjs do when they connect -- `?`, `$I`, `$$`, `$G` -- then unlocks
or homes, and streams a G-code file by character counting (GRBL's stream.py method:
keep the total length of unacknowledged lines within the 128-byte RX buffer).

Usage: grbl_sender.py PORT GCODE_FILE
Prints one JSON object with what it saw; exits non-zero on any protocol violation.
"""
import json
import re
import sys
import time

import serial

RX_BUFFER_SIZE = 128
TIMEOUT_S = 10.0


def fail(msg):
    print(json.dumps({"ok": False, "error": msg}))
    sys.exit(1)


class Grbl:
    def __init__(self, port):
        self.s = serial.Serial(port, 115200, timeout=0.05)
        self.s.reset_input_buffer()
        self.buf = b""

    def readline(self, deadline):
        while b"\n" not in self.buf:
            if time.monotonic() > deadline:
                return None
            self.buf += self.s.read(self.s.in_waiting or 1)
        line, self.buf = self.buf.split(b"\n", 1)
        return line.decode("ascii", "replace").strip()

    def lines_until_ok(self, what):
        deadline = time.monotonic() + TIMEOUT_S
        got = []
        while True:
            line = self.readline(deadline)
            if line is None:
                fail(f"no ok for {what}; got {got}")
            if not line:
                continue
            if line == "ok":
                return got
            if line.startswith("error:"):
                fail(f"{what} -> {line}")
            if line.startswith("ALARM:"):
                fail(f"{what} -> {line}")
            got.append(line)

    def command(self, cmd):
        self.s.write((cmd + "\n").encode("ascii"))
        return self.lines_until_ok(cmd)

    def status(self):
        self.s.write(b"?")
        deadline = time.monotonic() + TIMEOUT_S
        while True:
            line = self.readline(deadline)
            if line is None:
                fail("no status report")
            if line.startswith("<") and line.endswith(">"):
                return line


def main():
    port, path = sys.argv[1], sys.argv[2]
    g = Grbl(port)
    out = {"ok": True}

    # 1. Status, as UGS does first.
    st = g.status()
    m = re.match(r"^<(\w+)(:\d)?\|(MPos|WPos):(-?\d+\.\d+),(-?\d+\.\d+),(-?\d+\.\d+)", st)
    if not m:
        fail(f"bad status report {st!r}")
    out["first_state"] = m.group(1)

    # 2. $I: UGS requires [VER:...] matching this pattern.
    info = g.command("$I")
    ver = [l for l in info if l.startswith("[VER:")]
    if not ver or not re.match(r"^\[VER:(GD32 )?[vV]?\d+\.\d+[a-zA-Z]?.*?]$", ver[0]):
        fail(f"$I gave {info}")
    opt = [l for l in info if l.startswith("[OPT:")]
    if not opt:
        fail(f"no [OPT:] in {info}")
    out["version"] = ver[0]
    rx_size = int(opt[0][1:-1].split(",")[2])
    out["rx_buffer"] = rx_size

    # 3. $$: every line $n=value.
    settings = {}
    for l in g.command("$$"):
        mm = re.match(r"^\$(\d+)=(-?[\d.]+)", l)
        if not mm:
            fail(f"bad setting line {l!r}")
        settings[int(mm.group(1))] = float(mm.group(2))
    for n in (100, 101, 110, 111, 120, 121, 130, 131):
        if n not in settings:
            fail(f"$$ lacks ${n}")
    out["steps_per_mm_x"] = settings[100]

    # 4. $G.
    gc = g.command("$G")
    if not gc or not gc[0].startswith("[GC:"):
        fail(f"$G gave {gc}")
    out["parser_state"] = gc[0]

    # 5. Unlock by homing if enabled, else $X.
    if out["first_state"] == "Alarm":
        if settings.get(22, 0) == 1:
            g.s.write(b"$H\n")
            g.lines_until_ok("$H")
        else:
            g.command("$X")

    # 6. Stream by character counting.
    lines = [l.strip() for l in open(path)]
    in_flight = []
    acked = 0
    errors = []
    deadline = time.monotonic() + 60
    for l in lines:
        block = re.sub(r"\s|\(.*?\)|;.*", "", l).upper()
        data = block + "\n"
        in_flight.append(len(data))
        while sum(in_flight) >= RX_BUFFER_SIZE - 1 or g.s.in_waiting:
            line = g.readline(deadline)
            if line is None:
                fail(f"stream stalled after {acked} lines")
            if line == "ok" or line.startswith("error:"):
                if line.startswith("error:"):
                    errors.append((acked + 1, line))
                in_flight.pop(0)
                acked += 1
            elif line.startswith("ALARM:"):
                fail(f"{line} after {acked} lines")
        g.s.write(data.encode("ascii"))
    while in_flight:
        line = g.readline(deadline)
        if line is None:
            fail(f"stream stalled after {acked} lines")
        if line == "ok" or line.startswith("error:"):
            if line.startswith("error:"):
                errors.append((acked + 1, line))
            in_flight.pop(0)
            acked += 1
    out["streamed"] = len(lines)
    out["acknowledged"] = acked
    out["errors"] = errors

    # 7. Wait for Idle (status polling, 5 Hz as recommended... faster here).
    while True:
        st = g.status()
        if st.startswith("<Idle"):
            break
        if time.monotonic() > deadline:
            fail(f"never idle: {st}")
        time.sleep(0.02)
    out["final_status"] = st
    print(json.dumps(out))


if __name__ == "__main__":
    main()

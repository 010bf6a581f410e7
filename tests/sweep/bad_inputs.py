#!/usr/bin/env python3
"""The bad-input sweep (issue 25): crafted inputs for every file the gateway reads from
outside, each run through the real command line, each outcome classified.

For every surface (an outside file and the command that reads it) the sweep starts
from a valid seed (the fuzz corpora and the shipped configuration), derives crafted
inputs from it (special files, empty, truncated, garbage, bad UTF-8, every kind of
impossible number at several places, huge lines, deep nesting, size-cap files) and
runs the command on each with a time limit. Each outcome is one of:

  clear error   exit 1 or 2, a message on stderr naming the file, a line, a column
                or a field (what a user needs to find the fault)
  vague error   exit 1 or 2, the message names none of these
  accepted      exit 0 (listed in the report for review: a truncated CSV cut at a line
                end, say, is still a valid file; a non-finite number accepted is not)
  panic         exit 101 or "panicked" on stderr
  hang          still running at the time limit (killed)

and the peak memory (max RSS of the child, from wait4). Benign variants (CRLF line
ends, a byte-order mark) are expected to be accepted and are counted apart.

The G-code lines a sender streams through `gateway proxy` are a surface too
(`proxy_surface`: hostile lines in a live session, see PROXY_CASES).

Usage: python3 tests/sweep/bad_inputs.py [--gateway target/debug/gateway]
           [--timeout 20] [--report sweep-report.md]
Prints the per-surface table (markdown) and writes every input's outcome to the
report. Exit status 1 when any panic or hang was seen.
"""

import argparse
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CORPUS = os.path.join(ROOT, "tests", "fuzz", "corpus")
CONFIG = os.path.join(ROOT, "config")


def corpus(*p):
    return os.path.join(CORPUS, *p)


# --- the surfaces ---------------------------------------------------------------------
# name, seed file, file suffix, command (list; {in} the crafted file, {out} a fresh
# folder), numeric mutations (whether numbers in the seed are meaningful to mutate).
MAP = corpus("error_map_json", "small_map.json")
ERRORS = corpus("rotary_errors", "measured.json")
PROGRAM5 = corpus("rotary_rewrite", "program.nc")
BOARD = os.path.join(CONFIG, "boards", "dot-grid-0.5mm.toml")
# Made in the sweep's folder (see `seeds`): a program inside the small map, points
# inside the volumetric model's travel, a frame of the 0.5 mm dot grid.
PROGRAM = "{tmp}/program.nc"
# The map's reference record is found beside the map (`NAME.reference.json` for
# `NAME.json`): the crafted record is `{tmp}/input.v9.reference.json`, beside a copy of
# the small map made in `seeds`; its seed is a record of that map (issue 38).
RECORD_MAP = "{tmp}/input.v9.json"
LAYOUT = ["layout", "partition", "{in}", "--tools", "1", "--window-mm", "200",
          "--gap-mm", "0.5", "--clearance-mm", "0.001", "--out", "{out}/l.json"]

SURFACES = [
    ("error map (rewrite --map)", MAP, ".json",
     ["rewrite", PROGRAM, "--map", "{in}", "--out", "{out}/p.nc"]),
    ("error map (export)", MAP, ".json",
     ["export", "--map", "{in}", "--format", "csv", "--out", "{out}/t.csv"]),
    ("map reference record (rewrite)", corpus("reference_record", "small_map.json"),
     ".v9.reference.json", ["rewrite", PROGRAM, "--map", RECORD_MAP, "--out", "{out}/p.nc"]),
    ("G-code program (rewrite)", PROGRAM, ".nc",
     ["rewrite", "{in}", "--map", MAP, "--out", "{out}/p.nc"]),
    ("$# reply (rewrite --offsets)", corpus("dollar_hash", "grbl_reply.txt"), ".txt",
     ["rewrite", PROGRAM, "--map", MAP, "--offsets", "{in}", "--out", "{out}/p.nc"]),
    ("ISO 230-2 measurements", corpus("iso230_csv", "five_positions.csv"), ".csv",
     ["iso230", "evaluate", "{in}"]),
    ("rotary centres", corpus("rotary_centres", "paper.csv"), ".csv",
     ["rotary", "identify", "--centres", "{in}"]),
    ("rotary errors (rotary rewrite)", ERRORS, ".json",
     ["rotary", "rewrite", PROGRAM5, "--errors", "{in}", "--out", "{out}/p.nc"]),
    ("5-axis program (rotary rewrite)", PROGRAM5, ".nc",
     ["rotary", "rewrite", "{in}", "--errors", ERRORS, "--out", "{out}/p.nc"]),
    ("volumetric model", corpus("volumetric_model", "xyfz_identified.vol.csv"), ".csv",
     ["volumetric", "eval", "--model", "{in}", "--points", "{tmp}/points.csv"]),
    ("layout JSON", corpus("layout_json", "trousers.json"), ".json", LAYOUT),
    ("layout DXF", corpus("layout_dxf", "loops.dxf"), ".dxf", LAYOUT),
    ("layout SVG", corpus("layout_svg", "shapes.svg"), ".svg", LAYOUT),
    ("board file", os.path.join(CONFIG, "boards", "coded-0.5mm.toml"), ".toml",
     ["board", "make", "{in}", "-o", "{out}/art"]),
    ("board image (localize)", "{tmp}/frame.png", ".png",
     ["localize", "--board", BOARD, "--near", "10,10", "--um-per-px", "4", "{in}"]),
    # The job file, and the simulated machine's file it names (a job in the sweep's
    # folder names `input.m.toml`, the crafted file), each through a one-target run.
    ("job file (compensate)", "{tmp}/job.toml", ".job.toml",
     ["compensate", "--config", "{in}", "--targets", "1"]),
    ("machine file (compensate)", os.path.join(CONFIG, "machines", "c5-stage.toml"), ".m.toml",
     ["compensate", "--config", "{tmp}/machine-job.toml", "--targets", "1"]),
    ("Fanuc program (dnc --no-send)", "{tmp}/fanuc.nc", ".nc",
     ["dnc", "{in}", "--map", MAP, "--no-send", "--out", "{out}/t.nc"]),
]


def png_grey(width, height, pixel):
    """An 8-bit greyscale PNG (zlib and the PNG chunk layout, nothing else needed)."""
    import struct
    import zlib
    raw = b"".join(b"\0" + bytes(pixel(x, y) for x in range(width)) for y in range(height))

    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))


def seeds(tmp):
    """The seeds made for the sweep (each checked to be accepted before it is mutated)."""
    shutil.copy(MAP, os.path.join(tmp, "input.v9.json"))
    with open(os.path.join(tmp, "program.nc"), "w") as f:
        # Inside the map (0..100 x 0..50 mm) also with the seed's `$#` offsets
        # (G92 X+20, G55 Y-5.5).
        f.write("G21 G90\nG0 X10 Y10\nG1 X60 Y40 F1000\nG1 X20 Y10\n"
                "G2 X30 Y10 I5 J0\nG1 X70 Y30\nG0 X10 Y10\nM2\n")
    # The demo job with its files named absolutely (the crafted copies live elsewhere),
    # and one naming the crafted machine file beside it.
    with open(os.path.join(CONFIG, "gateway", "demo.toml")) as f:
        job = f.read().replace('"../', '"' + CONFIG + "/")
    with open(os.path.join(tmp, "job.toml"), "w") as f:
        f.write(job)
    with open(os.path.join(tmp, "machine-job.toml"), "w") as f:
        f.write(job.replace(CONFIG + "/machines/c5-stage.toml", "input.m.toml"))
    with open(os.path.join(tmp, "fanuc.nc"), "w") as f:
        f.write("%\nO1\nG90G21G00X10.Y10.\nG01X60.Y40.F1000.\nX20.Y10.\nM30\n%\n")
    with open(os.path.join(tmp, "points.csv"), "w") as f:
        f.write("x_mm,y_mm,z_mm\n100,100,100\n250,200,150\n")
    # The dot grid (0.5 mm pitch, 0.25 mm dots, dark on light) at 4 um/px, a dot at the
    # image centre; 640 x 480 px shows 5 x 4 dots.
    pitch, r = 125.0, 31.25

    def pixel(x, y):
        dx = (x - 320 + pitch / 2) % pitch - pitch / 2
        dy = (y - 240 + pitch / 2) % pitch - pitch / 2
        d = (dx * dx + dy * dy) ** 0.5
        return 30 if d < r - 0.5 else 220 if d > r + 0.5 else int(30 + 190 * (d - r + 0.5))
    with open(os.path.join(tmp, "frame.png"), "wb") as f:
        f.write(png_grey(640, 480, pixel))


NUMBER = re.compile(rb"(?<![A-Za-z_])-?\d+\.?\d*(?:[eE][-+]?\d+)?")
BAD_NUMBERS = [b"NaN", b"inf", b"-inf", b"1e308", b"-1e308", b"1e100", b"4e-320",
               b"99999999999999999999999"]


def variants(seed: bytes, suffix: str, rng: random.Random):
    """(name, kind, bytes | special) for one seed. kind: 'bad' or 'benign'."""
    out = []
    out.append(("empty file", "bad", b""))
    for frac in (0.5, 0.9):
        out.append((f"cut at {int(frac * 100)} %", "bad", seed[: int(len(seed) * frac)]))
    out.append(("cut mid-line (last 7 bytes gone)", "bad", seed[:-7]))
    out.append(("random bytes", "bad", bytes(rng.getrandbits(8) for _ in range(4096))))
    mid = len(seed) // 2
    out.append(("bytes not UTF-8 inside", "bad", seed[:mid] + b"\xff\xfe\xc3\x28" + seed[mid:]))
    out.append(("NUL bytes inside", "bad", seed[:mid] + b"\x00" * 16 + seed[mid:]))
    out.append(("one 8 MiB line appended", "bad", seed + b"9" * (8 << 20) + b"\n"))
    out.append(("the file 50 times", "bad", seed * 50))
    if suffix == ".png":
        return out + png_variants(seed)
    out.append(("CRLF line ends", "benign", seed.replace(b"\r\n", b"\n").replace(b"\n", b"\r\n")))
    out.append(("byte-order mark", "benign", b"\xef\xbb\xbf" + seed))
    if suffix.endswith(".json"):
        out.append(("JSON nested 100 000 deep", "bad", b"[" * 100_000 + b"]" * 100_000))
        out.append(("JSON of another type", "bad", b'"a string"'))
    # Numbers in comments (`#` to the line's end), in URLs and in quoted strings (a
    # machine's name) are not data.
    def is_data(m):
        line = seed[seed.rfind(b"\n", 0, m.start()) + 1: m.start()]
        return (b"#" not in line and b"http" not in line.split(b" ")[-1]
                and line.count(b'"') % 2 == 0)
    numbers = [m for m in NUMBER.finditer(seed) if is_data(m)]
    if numbers:
        picks = sorted(set(rng.randrange(len(numbers)) for _ in range(4)) | {0, len(numbers) - 1})
        for bad in BAD_NUMBERS:
            for k in picks:
                m = numbers[k]
                out.append((f"number #{k} -> {bad.decode()}", "bad",
                            seed[: m.start()] + bad + seed[m.end():]))
        everything = NUMBER.sub(lambda m: b"1e308", seed)
        out.append(("every number 1e308", "bad", everything))
    return out


def png_variants(seed):
    """A PNG's header claiming a huge image, and a chunk's checksum broken."""
    import struct
    import zlib
    out = []
    for w, h in ((100_000, 100_000), (1 << 31, 1), (0, 480)):
        ihdr = b"IHDR" + struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
        head = seed[:8] + struct.pack(">I", 13) + ihdr + struct.pack(">I", zlib.crc32(ihdr) & 0xFFFFFFFF)
        out.append((f"header claims {w} x {h} px", "bad", head + seed[33:]))
    broken = bytearray(seed)
    broken[29] ^= 0xFF
    out.append(("IHDR checksum broken", "bad", bytes(broken)))
    out.append(("16-bit RGBA header", "bad", seed[:24] + bytes([16, 6]) + seed[26:]))
    return out


SPECIAL = [
    ("a FIFO", "fifo"),
    ("/dev/zero", "/dev/zero"),
    ("a directory", "dir"),
    ("a symbolic link to /dev/zero", "link"),
    ("no such file", "missing"),
    ("over the size cap (sparse, 4 GiB)", "sparse"),
]


def materialise(tmp, name, suffix, what):
    path = os.path.join(tmp, "input" + suffix)
    for p in (path,):
        if os.path.islink(p) or os.path.isfile(p):
            os.unlink(p)
        elif os.path.isdir(p):
            shutil.rmtree(p)
        elif os.path.exists(p):
            os.unlink(p)
    if isinstance(what, bytes):
        with open(path, "wb") as f:
            f.write(what)
    elif what == "fifo":
        os.mkfifo(path)
    elif what == "/dev/zero" and suffix.endswith(".reference.json"):
        # A record is found beside its map, not named: a link there stands in.
        os.symlink("/dev/zero", path)
    elif what == "/dev/zero":
        return "/dev/zero"
    elif what == "dir":
        os.mkdir(path)
    elif what == "link":
        os.symlink("/dev/zero", path)
    elif what == "missing":
        pass
    elif what == "sparse":
        with open(path, "wb") as f:
            f.truncate(4 << 30)
    return path


def run(gateway, args, timeout):
    """(outcome, exit, stderr, peak KiB, seconds)."""
    t0 = time.monotonic()
    p = subprocess.Popen([gateway] + args, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                         start_new_session=True)
    deadline = t0 + timeout
    hung = False
    while True:
        pid, status, usage = os.wait4(p.pid, os.WNOHANG)
        if pid:
            break
        if time.monotonic() > deadline:
            hung = True
            os.killpg(p.pid, signal.SIGKILL)
            pid, status, usage = os.wait4(p.pid, 0)
            break
        time.sleep(0.02)  # polling a child process, not waiting on the gateway's work
    err = p.stderr.read().decode("utf-8", "replace")
    p.returncode = 0
    secs = time.monotonic() - t0
    code = os.waitstatus_to_exitcode(status)
    if hung:
        return "hang", code, err, usage.ru_maxrss, secs
    if code == 101 or "panicked" in err:
        return "panic", code, err, usage.ru_maxrss, secs
    if code < 0:
        return "panic", code, err, usage.ru_maxrss, secs  # killed by a signal (abort)
    if code == 0:
        return "accepted", code, err, usage.ru_maxrss, secs
    return "error", code, err, usage.ru_maxrss, secs


def is_clear(err, path):
    base = os.path.basename(path)
    return bool(
        base in err
        or re.search(r"\bline \d+", err)
        or re.search(r"\bcolumn\b", err)
        or re.search(r"`[A-Za-z_.\[\]0-9]+`", err)
        or re.search(r"error: --[a-z-]+: ", err)
        or re.search(r"\.(csv|toml|json):\d+", err)
        or "/dev/zero" in err
    )


# --- the pass-through: G-code lines from a sender through `gateway proxy` -------------
# Each case runs a fresh `gateway proxy --once` on the GRBL demo job (the emulated
# controller, its clock unconstrained) with a small map scanned in `proxy_seed`; the
# sweep opens the sender's port (`--link`), homes (`$H`, the gateway re-references),
# sends one move, then the case's lines, then a plain move that must still be answered
# `ok` (the session survived). A hostile line answered `error:N` is a clear error (GRBL's
# code, what a sender shows; most come with a `[MSG:gateway: ...]` naming the line); `ok`
# is accepted (listed for review); a soft reset (0x18) in a line is answered, as GRBL does,
# by `ALARM:3` and the banner (counted clear; the session is unlocked with `$X` before its
# last move); no answer within the time limit, or the port closed, is a hang; exit 101
# or "panicked" a panic.
PROXY_CASES = [
    ("a 8 KiB line", "bad", [b"G0 X1" + b"0" * 8192]),
    ("a 1 MiB line", "bad", [b"G1 X" + b"1" * (1 << 20) + b" F100"]),
    ("random bytes (no line ends)", "bad", None),  # filled from the seed in proxy_cases
    ("bytes not UTF-8", "bad", [b"G0 X\xff\xfe10 Y\xc3\x28"]),
    ("NUL bytes inside a line", "bad", [b"G0 X1\x00\x00Y2"]),
    ("a line of NUL bytes", "bad", [b"\x00" * 64]),
    ("an unterminated comment", "bad", [b"G1 X30 Y20 F500 (never closed"]),
    ("a comment never closed, then a move", "bad", [b"(open", b"G0 X12 Y12"]),
    ("nested comments", "bad", [b"G0 X10 (a (b) c) Y10"]),
    ("`$$` (settings)", "bad", [b"$$"]),
    ("`$I`, `$#`, `$G`", "bad", [b"$I", b"$#", b"$G"]),
    ("`$100=1e308`", "bad", [b"$100=1e308"]),
    ("`$100=nan`", "bad", [b"$100=nan"]),
    ("`$N0=G0 X1` (a startup line)", "bad", [b"$N0=G0 X1"]),
    ("`$J=G91 X1 F100` (a jog)", "bad", [b"$J=G91 X1 F100"]),
    ("`$C` (check mode) twice", "bad", [b"$C", b"G0 X50 Y50", b"$C"]),
    ("`$X` (unlock)", "bad", [b"$X"]),
    ("`$SLP` (sleep)", "bad", [b"$SLP"]),
    ("`$RST=#`", "bad", [b"$RST=#"]),
    ("`$` with 5000 characters", "bad", [b"$" + b"9" * 5000]),
    ("`?` mid-line (status)", "bad", [b"G0 X15?Y15"]),
    ("`!` mid-line (feed hold), then `~`", "bad", [b"G0 X16!Y16"]),
    ("`~` mid-line (cycle start)", "bad", [b"G0 X17~Y17"]),
    ("0x85 mid-line (jog cancel)", "bad", [b"G0 X18\x85Y18"]),
    ("0x90-0x9D mid-line (overrides)", "bad", [b"G1 X19 Y19 F900\x90\x91\x93\x95\x96\x99\x9d"]),
    ("0x18 mid-line (soft reset)", "bad", [b"G0 X21\x18Y21"]),
    ("0xA0 0xA1 mid-line (coolant)", "bad", [b"G0 X22\xa0\xa1Y22"]),
    ("`G0 X1e308`", "bad", [b"G0 X1e308"]),
    ("`G0 XNaN`", "bad", [b"G0 XNaN Y1"]),
    ("`G0 X99999999999999999999999`", "bad", [b"G0 X99999999999999999999999"]),
    ("`G1 F4e-320 X10`", "bad", [b"G1 F4e-320 X10"]),
    ("`G2` with R and I/J (error:36)", "bad", [b"G2 X60 Y50 I5 J5 R50 F600"]),
    ("`G91 G0 X1e6`", "bad", [b"G91 G0 X1000000", b"G90"]),
    ("`%` (program delimiter)", "bad", [b"%"]),
    ("`M30` then a move", "bad", [b"M30", b"G0 X10 Y10"]),
    ("a CR alone as line end", "bad", [b"G0 X23 Y23\rG0 X24 Y24"]),
    ("10^5 lines (send-response)", "bad", "many"),
    ("CRLF line ends", "benign", [b"G0 X25 Y25\r"]),
    ("lower case and blanks", "benign", [b"g0  x26 y 26"]),
    ("a comment-only line", "benign", [b"(just a comment)"]),
    ("a `;` comment", "benign", [b"G0 X27 Y27 ; to the corner"]),
    ("an empty line", "benign", [b""]),
]

MANY_LINES = 100_000


def proxy_seed(gateway, tmp):
    """The GRBL demo job (its files named absolutely) and a small map of its emulated
    machine, scanned once (about 3 s)."""
    with open(os.path.join(CONFIG, "gateway", "grbl-demo.toml")) as f:
        job = f.read().replace('"../', '"' + CONFIG + "/")
    path = os.path.join(tmp, "grbl-job.toml")
    with open(path, "w") as f:
        f.write(job)
    maps = os.path.join(tmp, "proxy-map")
    r = subprocess.run([gateway, "map", "--config", path, "--out", maps, "--grid-step-mm", "50",
                        "--line-step-mm", "50"], capture_output=True, timeout=600)
    if r.returncode != 0:
        sys.exit(f"proxy: the seed map could not be scanned: {r.stderr.decode()[-300:]}")
    return path, os.path.join(maps, "grbl-job.v1.json")


def proxy_session(gateway, tmp, job, seed_map, lines, timeout):
    """(outcome per hostile line, survived, exit, stderr, peak KiB, seconds)."""
    import select
    import termios
    import tty
    run_dir = tempfile.mkdtemp(dir=tmp)
    the_map = os.path.join(run_dir, "m.v1.json")
    shutil.copy(seed_map, the_map)  # its reference record is written beside it
    link = os.path.join(run_dir, "tty")
    t0 = time.monotonic()
    p = subprocess.Popen([gateway, "proxy", "--config", job, "--map", the_map, "--link", link,
                          "--once", "--time-scale", "unconstrained"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         stdin=subprocess.DEVNULL, start_new_session=True)
    answers, survived, fd = [], False, None
    try:
        while not os.path.exists(link):
            if p.poll() is not None or time.monotonic() - t0 > timeout:
                raise TimeoutError("the sender's port never appeared")
            time.sleep(0.02)  # polling for the port the child makes
        fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(fd)
        pending = b""

        def answer(line):
            """Send one line, read to its `ok` or `error:N` (status reports and
            messages skipped), or to GRBL's banner after a soft reset (0x18) in it. A
            feed hold (`!`) in a line is followed by a cycle start (`~`), as a sender
            would send: the hold keeps the answer until then."""
            nonlocal pending
            os.write(fd, line + b"\n")
            if b"!" in line and line.rfind(b"~") < line.rfind(b"!"):
                os.write(fd, b"~")
            deadline = time.monotonic() + timeout
            while True:
                while b"\n" in pending:
                    got, pending = pending.split(b"\n", 1)
                    got = got.strip()
                    if got == b"ok" or got.startswith(b"error:"):
                        return got.decode()
                    if got.startswith(b"Grbl ") and b"\x18" in line:
                        return "reset"
                left = deadline - time.monotonic()
                if left <= 0:
                    return "hang"
                r, _, _ = select.select([fd], [], [], min(left, 0.5))
                if r:
                    try:
                        data = os.read(fd, 1 << 16)
                    except OSError:
                        return "closed"
                    if not data:
                        return "closed"
                    pending += data

        for setup in (b"$H", b"G0 X20 Y20"):
            got = answer(setup)
            if got != "ok":
                raise RuntimeError(f"the session's set-up `{setup.decode()}` was answered {got}")
        if lines == "many":
            outcomes = {}
            for k in range(MANY_LINES):
                got = answer(b"G1 X%d Y%d F6000" % (20 + k % 2, 20 + (k // 2) % 2))
                outcomes[got] = outcomes.get(got, 0) + 1
                if got in ("hang", "closed"):
                    break
            answers.append(" ".join(f"{v} x {k}" for k, v in sorted(outcomes.items())))
            answers[-1] = "ok" if list(outcomes) == ["ok"] else answers[-1]
        else:
            for line in lines:
                answers.append(answer(line))
                if answers[-1] in ("hang", "closed"):
                    break
        if answers and answers[-1] not in ("hang", "closed"):
            # After a reset GRBL is locked (ALARM): a sender unlocks it first.
            if "reset" in answers and answer(b"$X") != "ok":
                survived = False
            else:
                survived = answer(b"G0 X10 Y10") == "ok"
    except (TimeoutError, RuntimeError, OSError) as e:
        answers.append(f"set-up failed: {e}")
    finally:
        if fd is not None:
            os.close(fd)
        try:
            os.killpg(p.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        try:
            _, status, usage = os.wait4(p.pid, 0)
        except ChildProcessError:
            status, usage = 0, None
        err = p.stderr.read().decode("utf-8", "replace")
        p.returncode = 0
        shutil.rmtree(run_dir, ignore_errors=True)
    code = os.waitstatus_to_exitcode(status)
    return answers, survived, code, err, usage.ru_maxrss if usage else 0, time.monotonic() - t0


def proxy_surface(gateway, tmp, timeout, rng, details):
    name = "G-code lines through `gateway proxy`"
    job, seed_map = proxy_seed(gateway, tmp)
    tally = {"clear error": 0, "vague error": 0, "accepted": 0, "panic": 0,
             "hang": 0, "benign accepted": 0, "benign refused": 0}
    peak = 0
    for case, kind, lines in PROXY_CASES:
        if lines is None:
            lines = [bytes(b for b in (rng.getrandbits(8) for _ in range(4096)) if b not in b"\r\n")]
        answers, survived, code, err, kib, secs = proxy_session(
            gateway, tmp, job, seed_map, lines, timeout)
        peak = max(peak, kib)
        hostile = answers[-1] if answers else "no answer"
        if "panicked" in err or code == 101:
            label = "panic"
        elif not survived:
            label = "hang" if kind == "bad" or "hang" in answers or "closed" in answers else "benign refused"
        elif kind == "benign":
            label = "benign accepted" if all(a == "ok" for a in answers) else "benign refused"
        elif any(a.startswith("error:") or a == "reset" for a in answers):
            label = "clear error"
        else:
            label = "accepted"
        tally[label] += 1
        said = "; ".join(answers)[:120] + ("" if survived else "; the session did not answer after it")
        last = err.strip().splitlines()[-1][:160] if err.strip() else ""
        last = "".join(c if c.isprintable() else "?" for c in last)
        details.append(f"| {name} | {case} | {label} | {code} | {kib // 1024} | {secs:.2f} | "
                       f"{said.replace('|', '/')} / {last.replace('|', '/')} |")
        print(f"  {case}: {label} ({said})", file=sys.stderr)
    hangs = tally["hang"]
    print(f"{name}: {len(PROXY_CASES)} inputs, {tally}, peak {peak // 1024} MiB", file=sys.stderr)
    return name, len(PROXY_CASES), tally, peak, hangs


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--gateway", default=os.path.join(ROOT, "target", "debug", "gateway"))
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--report", default="sweep-report.md")
    ap.add_argument("--only", default="", help="run surfaces whose name contains this")
    a = ap.parse_args()
    if not os.access(a.gateway, os.X_OK):
        sys.exit(f"no gateway binary at {a.gateway}: build it (cargo build -p gateway)")
    rng = random.Random(25)
    rows, details = [], []
    tmp = tempfile.mkdtemp(prefix="sweep-")
    seeds(tmp)
    # A board file names its certificate beside it.
    shutil.copy(os.path.join(CONFIG, "boards", "coded-0.5mm.certified.csv"), tmp)
    try:
        for name, seed_path, suffix, cmd in SURFACES:
            if a.only and a.only not in name:
                continue
            seed_path = seed_path.replace("{tmp}", tmp)
            seed = open(seed_path, "rb").read()
            cmd = [x.replace("{tmp}", tmp) for x in cmd]
            # The seed itself must be accepted, else every variant fails for its reason.
            out = os.path.join(tmp, "out")
            shutil.rmtree(out, ignore_errors=True)
            os.mkdir(out)
            path = materialise(tmp, "seed", suffix, seed)
            outcome, _, err, _, _ = run(a.gateway, [x.replace("{in}", path).replace("{out}", out)
                                                    for x in cmd], a.timeout)
            if outcome != "accepted":
                sys.exit(f"{name}: the seed {seed_path} is refused: {err.strip()[-300:]}")
            cases = [(n, "bad", w) for n, w in SPECIAL] + variants(seed, suffix, rng)
            tally = {"clear error": 0, "vague error": 0, "accepted": 0, "panic": 0,
                     "hang": 0, "benign accepted": 0, "benign refused": 0}
            peak = 0
            for case, kind, what in cases:
                out = os.path.join(tmp, "out")
                shutil.rmtree(out, ignore_errors=True)
                os.mkdir(out)
                path = materialise(tmp, case, suffix, what)
                args = [x.replace("{in}", path).replace("{out}", out) for x in cmd]
                outcome, code, err, kib, secs = run(a.gateway, args, a.timeout)
                peak = max(peak, kib)
                if kind == "benign":
                    label = "benign accepted" if outcome == "accepted" else (
                        outcome if outcome in ("panic", "hang") else "benign refused")
                elif outcome == "error":
                    label = "clear error" if is_clear(err, path) else "vague error"
                else:
                    label = outcome
                tally[label] += 1
                first = err.strip().splitlines()[-1][:200] if err.strip() else ""
                first = "".join(c if c.isprintable() else "?" for c in first)
                details.append(f"| {name} | {case} | {label} | {code} | {kib // 1024} | "
                               f"{secs:.2f} | {first.replace('|', '/')} |")
            rows.append((name, len(cases), tally, peak))
            print(f"{name}: {len(cases)} inputs, {tally}, peak {peak // 1024} MiB", file=sys.stderr)
        if not a.only or a.only in "G-code lines through `gateway proxy`":
            name, n, tally, peak, _ = proxy_surface(a.gateway, tmp, a.timeout, rng, details)
            rows.append((name, n, tally, peak))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    table = ["| surface | inputs | clear errors | vague errors | accepted (review) | "
             "panics | hangs | benign accepted / refused | peak memory |",
             "|---|---|---|---|---|---|---|---|---|"]
    total = {"n": 0, "panic": 0, "hang": 0}
    for name, n, t, peak in rows:
        table.append(f"| {name} | {n} | {t['clear error']} | {t['vague error']} | "
                     f"{t['accepted']} | {t['panic']} | {t['hang']} | "
                     f"{t['benign accepted']} / {t['benign refused']} | {peak // 1024} MiB |")
        total["n"] += n
        total["panic"] += t["panic"]
        total["hang"] += t["hang"]
    print("\n".join(table))
    with open(a.report + ".tmp", "w") as f:
        f.write("# Bad-input sweep\n\n" + "\n".join(table) + "\n\n")
        f.write("| surface | input | outcome | exit | peak MiB | s | last line of stderr |\n")
        f.write("|---|---|---|---|---|---|---|\n" + "\n".join(details) + "\n")
    os.replace(a.report + ".tmp", a.report)
    print(f"{total['n']} inputs; {total['panic']} panics, {total['hang']} hangs; "
          f"every outcome in {a.report}", file=sys.stderr)
    sys.exit(1 if total["panic"] or total["hang"] else 0)


if __name__ == "__main__":
    main()

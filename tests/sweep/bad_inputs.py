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

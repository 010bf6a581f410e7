#!/usr/bin/env python3
"""Converts a sparrow record layout (SVG: item shapes in <defs>, placed by <use> with
`translate(tx ty), rotate(r)`) into the layout JSON form of `layout-io`.

Usage: convert.py final_best_shirts.svg shirts > shirts.json
A point p of item k is placed at translate(t) . rotate(r) p (SVG applies the list right
to left). Coordinates stay in the instance's own units; the container's height becomes
width_mm. Part ids: <name>-<n>-item<k> in the order of the <use> elements.
"""
import json, math, re, sys
import xml.etree.ElementTree as ET

NS = "{http://www.w3.org/2000/svg}"
src, name = sys.argv[1], sys.argv[2]
root = ET.parse(src).getroot()

def path_points(d):
    nums = re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", d)
    assert re.fullmatch(r"\s*M[-+\d.eE,\s]*(L[-+\d.eE,\s]*)*z\s*", d), d
    v = list(map(float, nums))
    return [[v[i], v[i + 1]] for i in range(0, len(v), 2)]

items = {}
for g in root.iter(NS + "g"):
    gid = g.get("id", "")
    if gid.startswith("item_"):
        items[gid] = path_points(g.find(NS + "path").get("d"))
container = None
for g in root.iter():
    if g.get("id", "").startswith(("container", "bin")):
        pts = path_points(next(g.iter(NS + "path")).get("d"))
        container = max(p[1] for p in pts) - min(p[1] for p in pts)
def cross(o, a, b):
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

def crossing(a, b, c, d):
    return (cross(a, b, c) * cross(a, b, d) < 0) and (cross(c, d, a) * cross(c, d, b) < 0)

def repair(pts, pid):
    """Drops the tip of a spike that folds back over its own outline: where edge
    (i, i+1) crosses edge (i+2, i+3), vertex i+1 goes (a published shape of gardeyn7
    has one; our reader refuses self-intersecting contours). Each drop is reported."""
    changed = True
    while changed:
        changed = False
        n = len(pts)
        for i in range(n):
            a, b, c, d = (pts[(i + k) % n] for k in range(4))
            if crossing(a, b, c, d):
                print(f"{pid}: dropped vertex {b} (a spike crossing its outline)", file=sys.stderr)
                del pts[(i + 1) % n]
                changed = True
                break
    return pts

parts = []
for n, u in enumerate(root.iter(NS + "use")):
    ref = (u.get("href") or u.get("{http://www.w3.org/1999/xlink}href"))[1:]
    if not ref.startswith("item_"):  # cd_shape_*: the solver's collision shapes, not parts
        continue
    m = re.fullmatch(r"translate\(([-\d.eE]+) ([-\d.eE]+)\), rotate\(([-\d.eE]+)\)", u.get("transform"))
    tx, ty, r = map(float, m.groups())
    c, s = math.cos(math.radians(r)), math.sin(math.radians(r))
    pts = [[round(tx + c * x - s * y, 6), round(ty + s * x + c * y, 6)] for x, y in items[ref]]
    pid = f"{name}-{len(parts)}-{ref.replace('_', '')}"
    parts.append({"id": pid, "contours": [repair(pts, pid)]})
json.dump({"units": "mm", "width_mm": container, "parts": parts}, sys.stdout, separators=(",", ":"))
print()

#!/usr/bin/env python3
"""An independent renderer of dot-grid calibration frames, for testing the localizer on
images it was not developed against.

Nothing here is shared with the project's Rust renderer: the projection is a plane
homography (camera rotation, scale and a perspective tilt), dot coverage is estimated by
supersampling, the blur is a numpy separable Gaussian, illumination is a linear ramp,
noise is numpy's, and the PNG is written by hand with zlib.

Usage: render_board.py OUT.png --json  (prints the true board coordinate at the image
centre as JSON; all parameters have defaults, see --help)
"""
import argparse
import json
import math
import struct
import zlib

import numpy as np


def homography(args):
    """Pixel (x, y) -> board mm, as a 3x3 matrix."""
    cx, cy = (args.width - 1) / 2.0, (args.height - 1) / 2.0
    s = args.um_per_px / 1000.0
    t = math.radians(args.rotation_deg)
    c, n = math.cos(t), math.sin(t)
    # Image x along board (c, n); image y (down) along (n, -c): a camera looking down.
    affine = np.array(
        [
            [s * c, s * n, 0.0],
            [s * n, -s * c, 0.0],
            [0.0, 0.0, 1.0],
        ]
    )
    # Perspective tilt: a small projective term about the image centre (per pixel).
    persp = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [args.tilt_x, args.tilt_y, 1.0]])
    to_centre = np.array([[1.0, 0.0, -cx], [0.0, 1.0, -cy], [0.0, 0.0, 1.0]])
    to_pose = np.array([[1.0, 0.0, args.x_mm], [0.0, 1.0, args.y_mm], [0.0, 0.0, 1.0]])
    return to_pose @ affine @ persp @ to_centre


def render(args):
    h = homography(args)
    ss = args.supersample
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    r = args.dot_mm / 2.0
    cover = np.zeros((args.height, args.width))
    xs = np.arange(args.width, dtype=np.float64)
    for row in range(args.height):
        acc = np.zeros(args.width)
        for oy in offs:
            for ox in offs:
                px = xs + ox
                py = np.full_like(px, row + oy)
                w = h[2, 0] * px + h[2, 1] * py + h[2, 2]
                bx = (h[0, 0] * px + h[0, 1] * py + h[0, 2]) / w
                by = (h[1, 0] * px + h[1, 1] * py + h[1, 2]) / w
                gx = np.round(bx / args.pitch_mm) * args.pitch_mm
                gy = np.round(by / args.pitch_mm) * args.pitch_mm
                acc += ((bx - gx) ** 2 + (by - gy) ** 2) <= r * r
        cover[row] = acc / (ss * ss)
    if args.polarity == "dark-on-light":
        refl = args.light + (args.dark - args.light) * cover
    else:
        refl = args.dark + (args.light - args.dark) * cover
    yy, xx = np.mgrid[0 : args.height, 0 : args.width]
    ramp = 1.0 + args.gradient * ((xx - args.width / 2) / args.width)
    img = refl * ramp
    if args.blur > 0:
        k = int(math.ceil(4 * args.blur))
        t = np.arange(-k, k + 1)
        g = np.exp(-0.5 * (t / args.blur) ** 2)
        g /= g.sum()
        img = np.apply_along_axis(lambda m: np.convolve(np.pad(m, k, mode="edge"), g, "valid"), 1, img)
        img = np.apply_along_axis(lambda m: np.convolve(np.pad(m, k, mode="edge"), g, "valid"), 0, img)
    rng = np.random.default_rng(args.seed)
    img = img * 255.0 + rng.normal(0.0, args.noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8), h


def write_png(path, img):
    height, width = img.shape
    raw = b"".join(b"\x00" + img[y].tobytes() for y in range(height))

    def chunk(tag, data):
        body = tag + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(raw, 6)))
        f.write(chunk(b"IEND", b""))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--um-per-px", type=float, default=3.5)
    p.add_argument("--rotation-deg", type=float, default=1.5)
    p.add_argument("--tilt-x", type=float, default=2e-5, help="perspective term per pixel")
    p.add_argument("--tilt-y", type=float, default=-1.5e-5)
    p.add_argument("--x-mm", type=float, default=20.1234)
    p.add_argument("--y-mm", type=float, default=10.0567)
    p.add_argument("--pitch-mm", type=float, default=0.4)
    p.add_argument("--dot-mm", type=float, default=0.15)
    p.add_argument("--polarity", choices=["dark-on-light", "bright-on-dark"], default="bright-on-dark")
    p.add_argument("--light", type=float, default=0.85)
    p.add_argument("--dark", type=float, default=0.08)
    p.add_argument("--gradient", type=float, default=0.2)
    p.add_argument("--blur", type=float, default=1.2)
    p.add_argument("--noise", type=float, default=3.0)
    p.add_argument("--supersample", type=int, default=8)
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    img, h = render(args)
    write_png(args.out, img)
    cx, cy = (args.width - 1) / 2.0, (args.height - 1) / 2.0
    v = h @ np.array([cx, cy, 1.0])
    truth = {"x_mm": v[0] / v[2], "y_mm": v[1] / v[2]}
    print(json.dumps(truth) if args.json else truth)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""An exact reference for `voxserve bench peer`'s composite frames.

Renders a patch of pixels of the composite (unshaded) frame that both
`vtk_bench.py` and `voxserve bench peer` draw, in float64 with numpy, from
the definition alone: perspective rays through pixel centres from VTK's
camera, the volume's box with voxel centres at index × spacing (VTK's
convention), samples every `--step` voxels from where a ray enters the box,
trilinear interpolation, the transfer function of `vtk_bench.py`'s
`build_tfs` (read from the VTK functions it builds, so it is the same one),
opacity corrected to the step (unit distance: the smallest spacing),
front-to-back compositing over the background, then rounding to 8 bits.
Then it compares PNGs of the same frame (`bench peer --images`, and VTK's
`--png`) with it over the patch: their mean colour, their mean difference
from the reference, and their coverage as both benchmarks count it.

It settles which renderer's faint haze is right where their coverages
differ (the engine's): neither voxserve's nor VTK's code is used. It needs
the Python that `bench peer` uses for VTK (vtk and numpy; Pillow, for the
PNGs, comes with vtk's pip install).

    python tests/peer/exact_composite.py --raw ../shared/data/raw/engine_256x256x128_uint8.raw \\
        --dims 256 256 128 --dtype uint8 --tf-range 40 255 \\
        --camera "$(head -1 vtk.jsonl)" --patch 80 300 60 60 \\
        engine-composite-voxserve-0.png engine-composite-vtk-0.png

`--camera` takes `vtk_bench.py`'s first JSON line (or its "camera" object).
Prints one JSON line per image and one for the reference.
"""
import argparse
import json
import os
import sys

import numpy as np

BACKGROUND = np.array([0.1, 0.1, 0.12])
# A pixel counts toward coverage when its channels differ from the
# background by more than this in sum, of 255 (both benchmarks' count).
COVERAGE_THRESHOLD = 3


def transfer_function(vtk_bench, lo, hi):
    """`build_tfs`' colour and opacity nodes as (values, rgb) and (values, alpha)."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(vtk_bench)))
    from vtk_bench import build_tfs

    def nodes(function, width):
        # (x, values…, midpoint, sharpness) per node; build_tfs leaves
        # midpoint and sharpness at their defaults: piecewise linear.
        out = []
        for i in range(function.GetSize()):
            node = [0.0] * width
            function.GetNodeValue(i, node)
            out.append(node[:width - 2])
        return sorted(out)

    ctf, otf = build_tfs(lo, hi, "composite")
    colour, opacity = nodes(ctf, 6), nodes(otf, 4)
    return (np.array([n[0] for n in colour]), np.array([n[1:4] for n in colour]),
            np.array([n[0] for n in opacity]), np.array([n[1] for n in opacity]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--raw", required=True)
    ap.add_argument("--dims", type=int, nargs=3, required=True, metavar=("X", "Y", "Z"))
    ap.add_argument("--dtype", required=True, choices=["uint8", "uint16", "int16"])
    ap.add_argument("--endian", choices=["little", "big"], default="little")
    ap.add_argument("--spacing", type=float, nargs=3, default=[1.0, 1.0, 1.0])
    ap.add_argument("--tf-range", type=float, nargs=2, required=True, metavar=("LO", "HI"))
    ap.add_argument("--size", type=int, default=512, help="image edge in pixels (square)")
    ap.add_argument("--step", type=float, default=0.5, help="sample distance in voxels")
    ap.add_argument("--camera", required=True, help="vtk_bench.py's first JSON line")
    ap.add_argument("--patch", type=int, nargs=4, required=True, metavar=("X", "Y", "W", "H"),
                    help="pixels compared: first column, first row (from the top), width, height")
    ap.add_argument("--vtk-bench", default=os.path.join(os.path.dirname(__file__), "..", "..", "..",
                                                        "shared", "bench", "vtk_bench.py"))
    ap.add_argument("images", nargs="*", help="PNGs of the same frame to compare")
    args = ap.parse_args()

    dtype = np.dtype(args.dtype).newbyteorder("<" if args.endian == "little" else ">")
    nx, ny, nz = args.dims
    volume = np.fromfile(args.raw, dtype=dtype, count=nx * ny * nz)
    if volume.size != nx * ny * nz:
        sys.exit(f"--raw: {args.raw} holds {volume.size} voxels, expected {nx * ny * nz}")
    volume = volume.reshape(nz, ny, nx).astype(np.float64)
    dims = np.array(args.dims)
    spacing = np.array(args.spacing)
    x0, y0, w, h = args.patch
    if not (0 <= x0 and 0 <= y0 and 0 < w and 0 < h and x0 + w <= args.size
            and y0 + h <= args.size):
        sys.exit(f"--patch {args.patch}: expected a rectangle inside the {args.size}² image")
    camera = json.loads(args.camera)
    camera = camera.get("camera", camera)
    c_at, c_rgb, o_at, o_alpha = transfer_function(args.vtk_bench, *args.tf_range)

    # Rays through the patch's pixel centres.
    eye = np.array(camera["position"])
    forward = np.array(camera["focal_point"]) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.array(camera["view_up"]))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = np.tan(np.radians(camera["view_angle_deg"]) / 2)
    rows, cols = np.mgrid[y0:y0 + h, x0:x0 + w]
    ndc_x = (cols + 0.5) / args.size * 2 - 1
    ndc_y = 1 - (rows + 0.5) / args.size * 2
    dirs = forward + (ndc_x[..., None] * right + ndc_y[..., None] * up) * half
    dirs = (dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)).reshape(-1, 3)

    # Where each ray is inside the box of voxel centres.
    top = (dims - 1) * spacing
    with np.errstate(divide="ignore"):
        inverse = 1.0 / dirs
    low, high = (0.0 - eye) * inverse, (top - eye) * inverse
    enter = np.nan_to_num(np.minimum(low, high), nan=-np.inf).max(axis=1)
    leave = np.nan_to_num(np.maximum(low, high), nan=np.inf).min(axis=1)

    step = args.step * spacing.min()
    # The opacity correction's exponent: the step over the unit distance
    # (the smallest spacing), i.e. --step.
    exponent = args.step
    colour = np.zeros((len(dirs), 3))
    alpha = np.zeros(len(dirs))
    for k in range(int(np.ceil(max((leave - enter).max(), 0) / step)) + 1):
        t = enter + k * step
        inside = t <= leave
        if not inside.any():
            break
        p = (eye + dirs * t[:, None]) / spacing
        p = np.clip(p, 0, dims - 1)
        i = np.minimum(np.floor(p).astype(int), dims - 2)
        f = p - i
        value = np.zeros(len(dirs))
        for corner in range(8):
            d = [(corner >> axis) & 1 for axis in range(3)]
            weight = np.prod([f[:, axis] if d[axis] else 1 - f[:, axis] for axis in range(3)],
                             axis=0)
            value += weight * volume[i[:, 2] + d[2], i[:, 1] + d[1], i[:, 0] + d[0]]
        sample_alpha = 1 - (1 - np.interp(value, o_at, o_alpha)) ** exponent
        sample_alpha = np.where(inside, sample_alpha, 0.0)
        sample_rgb = np.stack([np.interp(value, c_at, c_rgb[:, c]) for c in range(3)], axis=-1)
        colour += ((1 - alpha) * sample_alpha)[:, None] * sample_rgb
        alpha += (1 - alpha) * sample_alpha
    exact = np.round(np.clip(colour + (1 - alpha)[:, None] * BACKGROUND, 0, 1) * 255)
    exact = exact.reshape(h, w, 3)

    background = np.round(BACKGROUND * 255)

    def coverage(rgb):
        return float((np.abs(rgb - background).sum(axis=-1) > COVERAGE_THRESHOLD).mean())

    print(json.dumps({"image": "exact", "patch": args.patch,
                      "mean_rgb": [round(float(v), 2) for v in exact.reshape(-1, 3).mean(axis=0)],
                      "coverage": round(coverage(exact), 4)}))
    if args.images:
        from PIL import Image
    for path in args.images:
        rgb = np.asarray(Image.open(path).convert("RGB")).astype(np.float64)
        if rgb.shape[:2] != (args.size, args.size):
            sys.exit(f"{path}: {rgb.shape[1]}×{rgb.shape[0]} pixels, expected --size {args.size}")
        rgb = rgb[y0:y0 + h, x0:x0 + w]
        print(json.dumps({
            "image": path, "patch": args.patch,
            "mean_rgb": [round(float(v), 2) for v in rgb.reshape(-1, 3).mean(axis=0)],
            "mean_abs_difference": round(float(np.abs(rgb - exact).sum(axis=-1).mean()), 3),
            "coverage": round(coverage(rgb), 4),
        }))


if __name__ == "__main__":
    main()

"""Cost of a change to the skin shader, paired in one process.

    .venv/bin/python tools/bench_shader.py --peer OTHER/shaders [--views 40] [--repeats 3] [--size 512] [--beam K]

Renders the RGB pass (skin shading with micro-detail) of one built-in body from the same
cameras (surface points at 4 cm to 1 m, log-uniform) with two renderers: one compiled from
this checkout's ``shaders/`` and one from ``--peer``'s,
alternating frame by frame. Between separate processes this 2-core machine's timings
drift by 15% or more; alternating in one process cancels that drift. Prints the median
process CPU time per frame (all llvmpipe threads) of each and the median of the
per-frame ratios (this checkout / peer).
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

import glsynth as gs  # noqa: E402
import glsynth.resources as resources  # noqa: E402
from glsynth.assets import make_body  # noqa: E402
from glsynth.lighting import Material, PointLight  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--peer", type=Path, required=True, help="the other checkout's shaders folder")
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--beam", type=float, default=0.0, metavar="K",
                    help="the light at the camera is a flash with a cos^K beam along the view")
    args = ap.parse_args()
    if not (args.peer / "skin.frag").is_file():
        ap.error(f"{args.peer} has no skin.frag")
    mesh = make_body(seed=args.seed).mesh
    rng = np.random.default_rng(args.seed)
    idx = rng.choice(len(mesh.vertices), args.views)
    dist = np.exp(rng.uniform(np.log(0.04), np.log(1.0), args.views))
    cams = [gs.Camera.from_surface(mesh.vertices[i], mesh.vertex_normals[i], float(w),
                                   width=args.size, height=args.size) for i, w in zip(idx, dist)]
    material = Material(model="skin", detail=True)

    def lights(cam):
        axis = np.subtract(cam.target, cam.eye)
        return [PointLight(cam.eye, beam_axis=axis, beam_exponent=args.beam)]

    folders = (resources.shader_dir(), args.peer.resolve())
    renderers = []
    own = resources.shader_dir
    for folder in folders:
        # programs are compiled on first use: render once with this folder's sources
        resources.shader_dir = lambda folder=folder: folder
        try:
            r = gs.Renderer(args.size, args.size)
            r.render(mesh, cams[0], passes=("rgb",), lights=lights(cams[0]), material=material)
        finally:
            resources.shader_dir = own
        renderers.append(r)
    times = ([], [])
    for _ in range(args.repeats):
        for cam in cams:
            for k, r in enumerate(renderers):
                t0 = time.process_time()
                r.render(mesh, cam, passes=("rgb",), lights=lights(cam), material=material)
                times[k].append(time.process_time() - t0)
    ours, peer = (1000 * statistics.median(t) for t in times)
    ratio = statistics.median(a / b for a, b in zip(*times))
    print(f"| shaders | CPU ms per {args.size}px RGB frame (median of {len(times[0])}) |\n|---|---:|")
    print(f"| this checkout ({folders[0]}) | {ours:.1f} |\n| peer ({folders[1]}) | {peer:.1f} |")
    print(f"\nmedian per-frame ratio, this checkout / peer: {ratio:.3f}")


if __name__ == "__main__":
    main()

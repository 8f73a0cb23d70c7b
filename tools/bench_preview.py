"""Frames per second of ``glsynth preview`` while orbiting a built-in body.

Every frame moves the camera (2 degrees of orbit), renders the displayed buffer with the
window's Renderer, copies it to the window and swaps buffers (the interactive loop's
work); the median over ``--frames`` frames after ``--warmup`` is printed as fps. Needs
a display: run it under a virtual X server on machines without one::

    xvfb-run -a -s "-screen 0 1280x1024x24" .venv/bin/python tools/bench_preview.py

Options: --size 1024x768 --body 0 --texture-size 1024 --buffer rgb (or 'all').
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import time

from glsynth.preview import BUFFERS, Viewer, load_scene, orbit, parse_size


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=parse_size, default=(1024, 768))
    ap.add_argument("--body", type=int, default=0)
    ap.add_argument("--texture-size", type=int, default=1024)
    ap.add_argument("--buffer", default="rgb", choices=BUFFERS + ("all",))
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--warmup", type=int, default=5)
    args = ap.parse_args(argv)
    scene = load_scene(argparse.Namespace(body=args.body, bodytex=None, mesh=None, blended=None,
                                          body_id=None, texture_size=args.texture_size))
    viewer = Viewer(scene, *args.size)
    try:
        print(f"GL_RENDERER: {viewer.renderer.info['GL_RENDERER']}; window "
              f"{viewer.size[0]}x{viewer.size[1]}; body seed {args.body}, texture "
              f"{args.texture_size}; {scene.mesh.faces.shape[0]} triangles")
        for buf in (BUFFERS if args.buffer == "all" else (args.buffer,)):
            viewer.set_buffer(buf)
            viewer.set_camera(viewer.home)
            times, cpu = [], []
            for i in range(args.warmup + args.frames):
                t0, c0 = time.perf_counter(), time.process_time()
                viewer.set_camera(orbit(viewer.camera, math.radians(2.0), 0.0))
                viewer.step()
                viewer.glfw.poll_events()
                if i >= args.warmup:
                    times.append(time.perf_counter() - t0)
                    cpu.append(time.process_time() - c0)
            med = statistics.median(times)
            # CPU time of all of this process's threads (llvmpipe renders on its own
            # threads): on a busy machine wall time overstates what an idle one needs.
            print(f"{buf:15s} median {med * 1000:6.1f} ms/frame  {1 / med:6.1f} fps  "
                  f"(min {min(times) * 1000:.1f} ms, max {max(times) * 1000:.1f} ms; "
                  f"CPU {statistics.median(cpu) * 1000:.1f} ms/frame; {len(times)} frames)")
        print(f"load average at the end: {', '.join(f'{x:.1f}' for x in os.getloadavg())} "
              f"on {os.cpu_count()} CPUs")
    finally:
        viewer.close()


if __name__ == "__main__":
    main()

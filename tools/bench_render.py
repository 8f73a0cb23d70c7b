"""Render-pass timings against pyrender, measured in one run.

    .venv/bin/python tools/bench_render.py [--size 512] [--frames 30] [--body builtin|procedural]

Prints a Markdown table: median milliseconds per frame (including read-back to numpy)
of (a) the G-buffer pass, (b) the shading pass, (c) all passes (G-buffer + shading +
label), and (d) pyrender colour + depth of the same mesh and cameras, with ratios
against (d), and GL_RENDERER.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

import glsynth as gs  # noqa: E402


def procedural_body(rng, tex_size=2048):
    """~27k triangles of capsules roughly shaped like a standing person."""
    import trimesh
    parts = []
    spec = [  # (radius, height, position, axis rotation about z in degrees)
        (0.16, 0.45, (0, 1.25, 0), 0), (0.1, 0.05, (0, 1.65, 0), 0),
        (0.07, 0.45, (-0.1, 0.55, 0), 0), (0.07, 0.45, (0.1, 0.55, 0), 0),
        (0.05, 0.5, (-0.35, 1.3, 0), 70), (0.05, 0.5, (0.35, 1.3, 0), -70)]
    for r, h, pos, rot in spec:
        c = trimesh.creation.capsule(height=h, radius=r, count=[48, 48])
        c.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
        c.apply_transform(trimesh.transformations.rotation_matrix(np.radians(rot), (0, 0, 1)))
        c.apply_translation(pos)
        parts.append(c)
    m = trimesh.util.concatenate(parts)
    v = np.asarray(m.vertices)
    uv = np.c_[0.5 + np.arctan2(v[:, 0], v[:, 2]) / (2 * np.pi), v[:, 1] / 1.8]
    tex = (rng.random((tex_size, tex_size, 3)) * 255).astype(np.uint8)
    return gs.Mesh(v, m.faces, uvs=uv, texture=tex, name="procedural-body")


def load_mesh(kind, rng):
    if kind == "builtin":
        try:
            return gs.assets.make_body(seed=0).mesh
        except Exception as exc:  # built-in bodies need anny; fall back honestly
            print(f"built-in body unavailable ({exc}); using the procedural one", file=sys.stderr)
    return procedural_body(rng)


def surface_cameras(mesh, rng, n, size):
    p = mesh.face_areas / mesh.face_areas.sum()
    faces = rng.choice(len(mesh.faces), size=n, p=p)
    cams = []
    for f in faces:
        point = mesh.vertices[mesh.faces[f]].mean(0)
        cams.append(gs.Camera.from_surface(point, mesh.face_normals[f], rng.uniform(0.4, 1.3),
                                           width=size, height=size))
    return cams


def median_ms(fn, cams, warmup=3):
    for c in cams[:warmup]:
        fn(c)
    times = []
    for c in cams:
        t = time.perf_counter()
        fn(c)
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--body", choices=("builtin", "procedural"), default="builtin")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    mesh = load_mesh(args.body, rng)
    cams = surface_cameras(mesh, rng, args.frames, args.size)
    labels = rng.integers(0, 3, size=(1024, 1024)).astype(np.uint16)
    r = gs.Renderer(args.size, args.size)
    light = lambda c: [gs.PointLight(c.eye)]  # noqa: E731
    rows = {
        "(a) G-buffer": lambda c: r.render(mesh, c, passes=("gbuffer",)),
        "(b) shading": lambda c: r.render(mesh, c, passes=("rgb",), lights=light(c)),
        "(c) all passes": lambda c: r.render(mesh, c, passes=("gbuffer", "rgb", "labels"),
                                             lights=light(c), label_texture=labels),
        "(e) a generated view's passes (2 label maps, 4x MSAA, shadows)":
            lambda c: r.render(mesh, c, passes=("gbuffer", "rgb", "labels"), lights=light(c),
                               label_textures={"a": labels, "b": labels}, multisample=4,
                               shadows=True),
    }
    results = {name: median_ms(fn, cams) for name, fn in rows.items()}
    peer = "(d) pyrender colour+depth"
    try:
        results[peer] = median_ms(pyrender_frame(mesh, args.size), cams)
    except Exception as exc:  # e.g. pyglet without X libraries on a headless GPU image
        print(f"pyrender unavailable ({type(exc).__name__}: {exc}); no peer column", file=sys.stderr)
    ref = results.get(peer)
    print(f"GL_RENDERER: {r.info['GL_RENDERER']}; mesh: {len(mesh.faces)} triangles, "
          f"texture {mesh.texture.shape[1]}x{mesh.texture.shape[0]}; {args.size}x{args.size}, "
          f"median of {args.frames} frames\n")
    print("| pass | median ms | ratio vs pyrender |\n|---|---:|---:|")
    for name, ms in results.items():
        print(f"| {name} | {ms:.1f} | {f'{ms / ref:.2f}' if ref else '-'} |")


def pyrender_frame(mesh, size):
    import pyrender
    import trimesh
    from PIL import Image
    corners = mesh.faces.reshape(-1)
    tm = trimesh.Trimesh(mesh.vertices[corners], np.arange(len(corners)).reshape(-1, 3),
                         process=False)
    tm.visual = trimesh.visual.TextureVisuals(uv=mesh.uvs[mesh.face_uvs.reshape(-1)],
                                              image=Image.fromarray(mesh.texture))
    scene = pyrender.Scene(ambient_light=(0.5, 0.5, 0.5))
    scene.add(pyrender.Mesh.from_trimesh(tm, smooth=False))
    cam_node = scene.add(pyrender.PerspectiveCamera(yfov=np.radians(30), znear=0.01, zfar=10))
    light_node = scene.add(pyrender.PointLight(intensity=1.0))
    offscreen = pyrender.OffscreenRenderer(size, size)

    def frame(cam):
        pose = np.linalg.inv(cam.view_matrix())
        scene.set_pose(cam_node, pose)
        scene.set_pose(light_node, pose)
        return offscreen.render(scene)
    return frame


if __name__ == "__main__":
    main()

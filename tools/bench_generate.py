"""End-to-end generation throughput and blend cost, measured in one run.

    .venv/bin/python tools/bench_generate.py [--views 40] [--short 10] [--repeats 3] [--blend-steps 400]
        [--workers 1,2] [--no-lesions] [--features] [--feature TEXT]

1. Annotated 512x512 samples per second for the default config (bodies cached, lesions
   pasted and blended beforehand) with 1 and 2 worker processes, with the per-stage split
   from the manifest. Each repeat runs ``--short`` and then ``--views`` views per body
   (2 bodies) in this process: the steady-state rate is the difference of the two runs
   (what a long dataset run sustains), the fixed cost is what a run spends beyond it
   (worker start-up, the first body's load, procedural rooms, COCO at the end), and the
   end-to-end rate is that of the longer run. Medians over ``--repeats``.
2. Seconds per lesion: procedural conditions (the default; their fields and decals, no
   blend), and lesion photographs (``lesions.source``, here pictures of procedural
   conditions written to a folder) pasted and blended: deep blend (paper settings, 400
   steps) with the weight-free filter bank, with VGG16 when weights are found locally,
   and Poisson; each includes the lesion's decal.
3. RGB-only generation against the default targets and against all eight targets
   (what leaving out unused passes, read-backs and writes saves), with the CPU time per
   sample in the steady state (all processes; on 2 cores, samples/s can be at most
   2000 / core-ms).
4. With ``--features``: the default targets with each realism feature of the default
   config turned off in turn (skin shading, micro-detail, clinical framing, flash,
   shadows, MSAA, camera model, clinical backdrops, frame-edge occluders), against the
   default row; ``--feature TEXT``: only the rows whose name holds TEXT, and no other table.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import tempfile
import time

import glsynth as gs
from glsynth.config import load_config
from glsynth.io.images import write_png
from glsynth.pipeline import generate
from glsynth.pipeline.runlock import FINGERPRINT, fingerprint


ALL_TARGETS = "outputs=[rgb,semantic,instances,anatomy,depth,normals,uv,face_id]"


def _cpu_seconds():
    """CPU time of this process and its finished children (worker processes)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _timed_run(overrides, workers, prepared):
    """(samples, wall seconds, CPU seconds, manifest) of one views run."""
    out = tempfile.mkdtemp(prefix="glsynth-bench-")
    shutil.copytree(f"{prepared}/bodies", f"{out}/bodies")
    cfg = load_config(None, overrides)
    _adopt(out, cfg)
    t0, c0 = time.perf_counter(), _cpu_seconds()
    manifest = generate(cfg, out, resume=True, workers=workers)
    dt, dc = time.perf_counter() - t0, _cpu_seconds() - c0
    shutil.rmtree(out)
    return manifest["counts"]["images"], dt, dc, manifest


def _adopt(out, cfg):
    """Mark the copied bodies as this config's run: they do not depend on the settings
    the benchmark varies (views per body, outputs), which a real resume would refuse."""
    with open(os.path.join(out, FINGERPRINT), "w") as fh:
        json.dump(fingerprint(cfg), fh)


def _lesion_photographs(root, n=6, seed=0, size=256):
    """A lesion folder in the pairs layout: pictures of procedural conditions."""
    os.makedirs(root, exist_ok=True)
    for i, les in enumerate(gs.assets.procedural_lesions(n, seed=seed, size=size)):
        write_png(f"{root}/lesion{i}.png", les.image)
        write_png(f"{root}/lesion{i}_segmentation.png", les.mask.astype("uint8") * 255)
    return root


def _views_run(overrides, workers, repeats, prepared, views, short):
    """Medians over repeats of: steady-state samples/s and CPU ms per sample (the
    difference between a ``short`` and a ``views`` views-per-body run), the fixed
    seconds per run beyond the steady state, and the longer run's end-to-end samples/s
    (paste/blend results reused)."""
    steady, cpu, fixed, end_to_end, manifest = [], [], [], [], None
    for _ in range(repeats):
        n0, t0, c0, _ = _timed_run(overrides + [f"views.per_body={short}"], workers, prepared)
        n1, t1, c1, manifest = _timed_run(overrides + [f"views.per_body={views}"], workers, prepared)
        rate = (n1 - n0) / (t1 - t0)
        steady.append(rate)
        cpu.append(1e3 * (c1 - c0) / (n1 - n0))
        fixed.append(t1 - n1 / rate)
        end_to_end.append(n1 / t1)
    med = statistics.median
    return med(steady), med(cpu), med(fixed), med(end_to_end), manifest


# What each realism feature of the default config costs: the views stage with it off.
FEATURES = (
    ("skin shading, detail and hair (-> Phong)", ["views.shading=phong"]),
    ("micro-detail and hair", ["views.detail=false"]),
    ("clinical framing (-> in-the-wild only)", ["views.framing={wild: 1.0}"]),
    ("flash", ["views.flash=0", "views.closeup_flash=0"]),
    ("soft shadows", ["views.shadows=false"]),
    ("ambient occlusion (cached after a body's first bake)", ["views.occlusion=false"]),
    ("4x MSAA", ["views.multisample=0"]),
    ("camera model", ["photo.enabled=false"]),
    ("clinical backdrops (-> rooms)", ["backgrounds.clinical=0"]),
    ("gloves, clothing and drapes at the frame's edge", ["backgrounds.edges=0"]),
)


def _feature_costs(args, prepared):
    """CPU per sample with each feature off against the default measured just before it
    (this VM's speed drifts by 10-30% within minutes, so each pair runs back to back).
    Each is the whole CPU time of a ``--views`` run over its samples: the difference of
    two runs, which the steady state uses, is too noisy for a ~10% effect."""
    print("## What each feature costs (default targets, 1 worker, the feature turned off)\n")
    print(f"Each row: CPU core-ms per sample of {2 * args.views}-sample runs (whole run), the default "
          f"and then the feature off, back to back; medians of {args.repeats}.\n")
    print("| turned off | override | default | with it off | the feature's share |")
    print("|---|---|---:|---:|---:|")
    views = [f"views.per_body={args.views}"]
    for name, overrides in FEATURES:
        if args.feature and args.feature not in name:
            continue
        on, off = [], []
        for _ in range(args.repeats):
            n, _, c, _ = _timed_run(views, 1, prepared)
            on.append(1e3 * c / n)
            n, _, c, _ = _timed_run(overrides + views, 1, prepared)
            off.append(1e3 * c / n)
        a, b = statistics.median(on), statistics.median(off)
        print(f"| {name} | `{' '.join(overrides)}` | {a:.0f} | {b:.0f} | {(a - b) / a:+.0%} |", flush=True)
    print()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=40, help="views per body (2 bodies), longer run")
    ap.add_argument("--short", type=int, default=10, help="views per body of the shorter run")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--blend-steps", type=int, default=400)
    ap.add_argument("--workers", default="1,2",
                    help="comma-separated worker counts for the default and RGB-only rows")
    ap.add_argument("--no-lesions", action="store_true", help="leave out the seconds-per-lesion table")
    ap.add_argument("--features", action="store_true",
                    help="also time the default targets with each realism feature turned off in turn")
    ap.add_argument("--feature", default="",
                    help="only the feature rows whose name holds this text, and no other table")
    args = ap.parse_args(argv)
    counts = tuple(int(n) for n in args.workers.split(","))
    base = [f"views.per_body={args.views}"]

    prepared = tempfile.mkdtemp(prefix="glsynth-prep-")
    generate(load_config(None, base + ["views.per_body=0"]), prepared)  # bodies, paste, blend
    if args.feature:
        _feature_costs(args, prepared)
        shutil.rmtree(prepared)
        return

    print("## Samples per second (512x512, default config, views stage incl. writing)\n")
    print(f"Steady state: the difference between runs of {2 * args.short} and {2 * args.views} samples; "
          f"end to end: the {2 * args.views}-sample run; medians of {args.repeats}.\n")
    print("| outputs | workers | samples/s, steady state | CPU core-ms per sample | fixed s per run "
          f"| samples/s, {2 * args.views} end to end | per-stage seconds (longer run, summed over workers) |")
    print("|---|---:|---:|---:|---:|---:|---|")
    rows = {}
    for name, extra, worker_counts in (("default (5 targets)", [], counts),
                                       ("all 8 targets", [ALL_TARGETS], counts[:1]),
                                       ("RGB only", ["outputs=[rgb]"], counts)):
        for workers in worker_counts:
            rate, cpu, fixed, e2e, man = _views_run(extra, workers, args.repeats, prepared,
                                                    args.views, args.short)
            rows[(name, workers)] = rate
            split = {k: v for k, v in man["timings_seconds"].items() if k != "total"}
            print(f"| {name} | {workers} | {rate:.2f} | {cpu:.0f} | {fixed:.2f} | {e2e:.2f} | "
                  f"{json.dumps(split)} |", flush=True)
    one, most = counts[0], counts[-1]
    rgb = rows[("RGB only", one)]
    print(f"\nSteady state, RGB-only vs default targets: {rgb / rows[('default (5 targets)', one)]:.2f}x, "
          f"vs all 8 targets: {rgb / rows[('all 8 targets', one)]:.2f}x ({one} worker(s)); {most} vs {one} "
          f"workers (default): {rows[('default (5 targets)', most)] / rows[('default (5 targets)', one)]:.2f}x")
    print(f"GL_RENDERER: {man['gl_renderer']}\n")

    if args.features:
        _feature_costs(args, prepared)
    if args.no_lesions:
        shutil.rmtree(prepared)
        return
    print(f"## Seconds per lesion (paper settings, {args.blend_steps} steps for deep; incl. decals)\n")
    print("| lesions | method | features | seconds per lesion |\n|---|---|---|---:|")
    from glsynth.pipeline.features import find_vgg_weights
    photos = _lesion_photographs(tempfile.mkdtemp(prefix="glsynth-lesions-"))
    image_source = [f"lesions.source={photos}", "lesions.layout=pairs"]
    variants = [("procedural", [], "-"), ("photographs", image_source + ["blend.method=poisson"], "-"),
                ("photographs", image_source + ["blend.method=deep", f"blend.steps={args.blend_steps}"],
                 "filters")]
    if find_vgg_weights() is not None:
        variants.append(("photographs", image_source + ["blend.method=deep", "blend.features=vgg16",
                                                        f"blend.steps={args.blend_steps}"], "vgg16"))
    for name, overrides, feats in variants:
        out = tempfile.mkdtemp(prefix="glsynth-blend-")
        cfg = load_config(None, base + ["views.per_body=0"] + overrides)
        generate(cfg, out)  # bodies and paste; then blend again, timed alone
        for b in ("body000", "body001"):
            for f in ("blended.png", "blend.json", "decals.npz"):
                p = f"{out}/bodies/{b}/{f}"
                if os.path.exists(p):
                    os.unlink(p)
        stage = gs.BlendLesions(cfg, out)
        t0 = time.perf_counter()
        stage.blend_lesions()
        dt = time.perf_counter() - t0
        n = sum(len(json.load(open(f"{out}/bodies/{b}/placements.json"))) for b in ("body000", "body001"))
        method = cfg.blend.method if name == "photographs" else "fields (no blend)"
        print(f"| {name} | {method} | {feats} | {dt / max(n, 1):.2f} |", flush=True)
        shutil.rmtree(out)
    shutil.rmtree(photos)
    shutil.rmtree(prepared)


if __name__ == "__main__":
    main()

"""The ``glsynth`` command line."""
from __future__ import annotations

import argparse
import logging
import sys

from .errors import GlsynthError, describe


def _config(args):
    from .config import load_config
    return load_config(args.config, args.set or ())


def _add_config_args(p, out=True):
    p.add_argument("--config", default=None, help="YAML config (default: the embedded configs/default.yaml)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a config value, e.g. --set views.per_body=20 (repeatable)")
    if out:
        p.add_argument("--out", required=True, help="output folder")


def cmd_generate(args):
    from .pipeline import generate
    cfg = _config(args)
    manifest = generate(cfg, args.out, resume=args.resume, workers=args.workers,
                        executor=args.executor, address=args.ray_address)
    c = manifest["counts"]
    print(f"{c['images']} images, {c['lesion_annotations']} lesion annotations in {args.out} "
          f"({manifest['timings_seconds']['total']:.1f} s)")


def cmd_stage(args):
    from . import pipeline
    from .pipeline.inputs import open_inputs
    from .pipeline.runlock import open_run
    cfg = _config(args)
    stage, method = {"paste": (pipeline.SelectAndPaste, "paste_on_locations"),
                     "blend": (pipeline.BlendLesions, "blend_lesions"),
                     "views": (pipeline.Generate2DViews, "synthesize_views")}[args.command]
    # a stage continues the run in --out: same fingerprint, and no other process there
    with open_run(args.out, cfg, resume=True):
        inputs = open_inputs(cfg, stages=(args.command,))
        getattr(stage(cfg, args.out, inputs=inputs), method)()


def cmd_show(args):
    from .show import contact_sheet
    path = contact_sheet(args.dir, args.out, n=args.n)
    print(f"wrote {path}")


def cmd_info(args):
    from .gl.renderer import Renderer
    r = Renderer(8, 8, backend=args.backend)
    for k in ("GL_RENDERER", "GL_VERSION", "GL_VENDOR"):
        print(f"{k}: {r.info[k]}")


def main(argv=None):
    ap = argparse.ArgumentParser(prog="glsynth", description="Synthetic in-the-wild dermatology "
                                 "images with dense labels")
    ap.add_argument("-v", "--verbose", action="store_true")
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("generate", help="run the whole pipeline into a dataset folder")
    _add_config_args(p)
    p.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    p.add_argument("--workers", type=int, default=1,
                   help="processes (or Ray actors), each with its own GL context (default 1)")
    p.add_argument("--executor", choices=("local", "ray"), default="local")
    p.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local one)")
    p.set_defaults(fn=cmd_generate)
    for name, text in (("paste", "select locations and paste lesions into body textures"),
                       ("blend", "blend pasted lesions (needs paste)"),
                       ("views", "render annotated views (uses blend or paste results)")):
        p = sub.add_parser(name, help=text)
        _add_config_args(p)
        p.set_defaults(fn=cmd_stage)
    p = sub.add_parser("show", help="contact sheet of a dataset: image, boxes, semantic, anatomy, depth")
    p.add_argument("dir")
    p.add_argument("--out", required=True, help="PNG to write")
    p.add_argument("-n", type=int, default=6, help="number of samples")
    p.set_defaults(fn=cmd_show)
    # Commands that live in their own modules register themselves here.
    for module in ("glsynth.preview", "glsynth.assets.sheets", "glsynth.train.cli",
                   "glsynth.train.sim2real"):
        try:
            mod = __import__(module, fromlist=["register"])
        except ModuleNotFoundError as exc:
            if not module.startswith(exc.name or "?"):  # a missing import inside it is a bug
                raise
            continue
        mod.register(sub)
    p = sub.add_parser("info", help="print the OpenGL renderer in use")
    p.add_argument("--backend", default=None)
    p.set_defaults(fn=cmd_info)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    # Expected failures (bad input, unusable files, OS errors) are one line and exit 2;
    # anything else is a bug and keeps its traceback.
    try:
        args.fn(args)
        return 0
    except KeyboardInterrupt:
        hint = "; continue with --resume" if args.command == "generate" else ""
        rc, message = 130, f"interrupted{hint}"
    except (GlsynthError, OSError) as exc:
        rc, message = 2, f"error: {describe(exc)}"
    # said once the failed call's frames are gone: their progress bars have closed by then
    print(f"glsynth {args.command}: {message}", file=sys.stderr)
    return rc


if __name__ == "__main__":
    sys.exit(main())

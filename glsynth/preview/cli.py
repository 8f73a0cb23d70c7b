"""``glsynth preview``: its arguments and the command."""
from __future__ import annotations

import argparse

from ..errors import InputError
from ..optional import require
from .buffers import BUFFERS
from .controls import KEY_HELP
from .scene import load_scene, parse_view
from .viewer import Viewer
from .window import glfw

DEFAULT_SIZE = (1024, 768)


def parse_size(text):
    """(width, height) from 'WIDTHxHEIGHT'."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w < 1 or h < 1:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 1024x768, got {text!r}") from None
    return w, h


def register(subparsers):
    p = subparsers.add_parser(
        "preview", help="interactive window: orbit a body, switch buffers, inspect labels",
        description="Interactive OpenGL preview of a body, shaded as `glsynth generate` shades "
                    "its views (press H in the window for the keys). Needs a display (or "
                    "xvfb-run -a) and the preview extra (pip install 'glsynth[preview]').")
    src = p.add_argument_group("what to show (default --body 0)")
    src.add_argument("--body", type=int, default=None, metavar="SEED", help="built-in body from this seed")
    src.add_argument("--bodytex", default=None, metavar="FOLDER", help="a 3DBodyTex-layout scan folder")
    src.add_argument("--mesh", default=None, metavar="FILE", help="any textured mesh (OBJ, PLY, GLB...)")
    src.add_argument("--blended", default=None, metavar="DIR",
                     help="a `glsynth generate` output folder: show a body with its blended lesions, "
                          "rendered with the run's config")
    src.add_argument("--body-id", default=None, help="the body of the --blended run (default: the first)")
    src.add_argument("--texture-size", type=int, default=1024,
                     help="texture size of built-in bodies and re-atlased meshes (default 1024)")
    src.add_argument("--config", default=None,
                     help="YAML config whose views settings (shading, multisample, shadows...) the "
                          "preview renders with (default: the embedded configs/default.yaml)")
    src.add_argument("--set", action="append", metavar="KEY=VALUE",
                     help="override a config value, e.g. --set views.shadows=false (repeatable)")
    p.add_argument("--size", type=parse_size, default=None, metavar="WxH",
                   help="window size (default: the --camera record's image size, else 1024x768)")
    p.add_argument("--buffer", choices=BUFFERS, default="rgb", help="buffer shown first")
    p.add_argument("--camera", default=None, metavar="JSON",
                   help="start view: JSON string or file with a Camera.to_dict() dict, the C-key "
                        "snippet, or a dataset's targets/<id>.json (camera, lights and material)")
    p.add_argument("--save-dir", default="preview", help="where P saves screenshots and targets (./preview)")
    auto = p.add_argument_group("non-interactive mode")
    auto.add_argument("--screenshot", default=None, metavar="PATH",
                      help="after --frames frames, save the window's framebuffer as PNG and exit")
    auto.add_argument("--frames", type=int, default=None, help="render this many frames, then exit")
    auto.add_argument("--keys", default="", help="keys to press first, one per frame, comma-separated "
                                                  "(e.g. 'n,3,shift+left,c')")
    p.set_defaults(fn=cmd_preview)


def cmd_preview(args):
    require(glfw)  # before a body is built for nothing
    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames must be >= 1, got {args.frames}")
    if args.texture_size < 16:
        raise InputError(f"--texture-size must be >= 16, got {args.texture_size}")
    frames = args.frames if args.frames is not None else (1 if args.screenshot else None)
    start = parse_view(args.camera) if args.camera else None
    size = args.size or (start.size if start is not None and start.size else DEFAULT_SIZE)
    scene = load_scene(args)
    viewer = Viewer(scene, *size, camera=start.camera if start else None,
                    lights=start.lights if start else None, material=start.material if start else None,
                    buffer=args.buffer, save_dir=args.save_dir)
    try:
        if frames is None:
            print(KEY_HELP, flush=True)
        keys = [k.strip() for k in args.keys.split(",") if k.strip()]
        viewer.run(frames=frames, screenshot=args.screenshot, keys=keys)
    finally:
        viewer.close()

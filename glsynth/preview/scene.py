"""What the previewer shows: a body, its texture and lesion ids, the view settings of
``glsynth generate``, and a start view read from a snippet or a per-image record."""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

from .. import dataformat as fmt
from ..errors import InputError


@dataclass
class PreviewScene:
    """A body, its (blended) texture, lesion instance map and the placements of a
    ``glsynth generate`` run (empty without ``--blended``), and ``views``: the config's
    view settings (``ViewsConfig``) that ``generate`` renders with: shading model,
    multisampling, supersampling, shadows. None: those of the embedded default config."""

    body: object                  # glsynth.assets.Body
    mesh: object                  # body.mesh with the displayed texture
    instances: np.ndarray         # uint16 texture-space lesion ids
    placements: list = field(default_factory=list)   # dicts from placements.json
    body_id: str = "body"
    views: object = None

    def __post_init__(self):
        if self.views is None:
            from ..config import load_config
            self.views = load_config(None).views


def load_scene(args) -> PreviewScene:
    """The body and textures named by the command-line arguments (``--body``,
    ``--bodytex``, ``--mesh`` or ``--blended`` with ``--body-id``; ``--config`` and
    ``--set`` choose the view settings, except for a run, which has its own)."""
    from .. import assets
    from ..config import load_config
    given = [n for n in ("body", "bodytex", "mesh") if getattr(args, n, None) is not None]
    if len(given) > 1:
        raise InputError(f"choose one of --body, --bodytex, --mesh (got {', '.join('--' + g for g in given)})")
    config, overrides = getattr(args, "config", None), getattr(args, "set", None) or ()
    if args.blended is not None:
        if given:
            raise InputError("--blended takes its bodies from that run's config: choose one "
                             "with --body-id (e.g. --body-id body000), not --" + given[0])
        if config is not None or overrides:
            raise InputError("--blended renders with that run's own config: drop --config and --set")
        return load_run_body(args.blended, args.body_id)
    if args.body_id is not None:
        raise InputError("--body-id chooses a body of a --blended run; pass --blended DIR too")
    views = load_config(config, overrides).views
    if given == ["bodytex"]:
        body, bid = assets.load_bodytex(args.bodytex), os.path.basename(os.path.normpath(args.bodytex))
    elif given == ["mesh"]:
        body = assets.load_mesh_body(args.mesh, texture_size=args.texture_size)
        bid = os.path.splitext(os.path.basename(args.mesh))[0]
    else:
        seed = 0 if args.body is None else args.body
        body, bid = assets.make_body(seed=seed, texture_size=args.texture_size), f"seed{seed}"
    h, w = body.mesh.texture.shape[:2]
    return PreviewScene(body, body.mesh, np.zeros((h, w), np.uint16), [], bid, views)


def load_run_body(folder, body_id=None) -> PreviewScene:
    """A body of a ``glsynth generate`` run as its views see it: rebuilt from the run's
    config, with its blended (else pasted) texture, lesion decals, ids and placements."""
    from ..io.images import read_image, read_rgb
    from ..pipeline.bodies import load_body
    run = fmt.RunFolder(folder)
    try:
        cfg = run.config()
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"--blended {exc}") from None
    available = run.body_ids()
    if not available:
        raise FileNotFoundError(f"--blended {run.root}: no bodies/<id>/ folders (was the run made "
                                "with lesions.per_body = 0?)")
    body_id = body_id or available[0]
    if body_id not in available:
        raise FileNotFoundError(f"--blended {run.root}: no body {body_id!r}; it has {', '.join(available)}")
    body = load_body(cfg, body_id)
    tex_path = next((run.body_path(body_id, n) for n in (fmt.BLENDED, fmt.PASTED)
                     if os.path.isfile(run.body_path(body_id, n))), None)
    if tex_path is None:
        raise FileNotFoundError(f"{run.body_path(body_id)}: neither {fmt.BLENDED} nor {fmt.PASTED}")
    texture = read_rgb(tex_path)
    hw = body.mesh.texture.shape[:2]
    if texture.shape[:2] != hw:
        raise InputError(f"{tex_path}: texture is {texture.shape[1]}x{texture.shape[0]} but body "
                         f"{body_id} has a {hw[1]}x{hw[0]} texture (config changed since the run?)")
    inst_path = run.body_path(body_id, fmt.BODY_INSTANCES)
    if os.path.isfile(inst_path):
        instances = read_image(inst_path).astype(np.uint16)
        if instances.shape != hw:
            raise InputError(f"{inst_path}: instance map is {instances.shape[1]}x{instances.shape[0]}, "
                             f"texture is {hw[1]}x{hw[0]}")
    else:
        instances = np.zeros(hw, np.uint16)
    placements = []
    if os.path.isfile(run.body_path(body_id, fmt.PLACEMENTS)):
        with open(run.body_path(body_id, fmt.PLACEMENTS)) as fh:
            placements = json.load(fh)
    from ..pipeline.decals import Decals
    decals = Decals.load(run.body_path(body_id)) if placements else None
    return PreviewScene(body, body.mesh.copy_with(texture=texture, decals=decals), instances,
                        placements, body_id, cfg.views)


@dataclass
class StartView:
    """A view read by :func:`parse_view`: the camera, and the lights, material and image
    size when the source has them (None otherwise)."""

    camera: object
    lights: list | None = None
    material: object = None
    size: tuple | None = None


def parse_view(text) -> StartView:
    """The view in a JSON string or a JSON/YAML file: a ``Camera.to_dict()`` dict, the
    snippet the C key prints ({"camera", "light", "lights", "material"}) or a dataset's
    per-image record (``targets/<id>.json``, which also gives the image size)."""
    src = "--camera"
    if os.path.isfile(text):
        src = text
        with open(text) as fh:
            text = fh.read()
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        try:
            import yaml
            d = yaml.safe_load(text)
        except Exception:
            raise InputError(f"{src}: not JSON or YAML ({exc})") from None
    if not isinstance(d, dict):
        raise InputError(f"{src}: expected a camera dict (Camera.to_dict()), got {type(d).__name__}")
    cam_d = d.get("camera", d)
    if not isinstance(cam_d, dict) or "eye" not in cam_d or "target" not in cam_d:
        raise InputError(f"{src}: a camera needs 'eye' and 'target' (as Camera.to_dict() writes)")
    try:
        view = StartView(fmt.camera_from_record(d))
        if "lights" in d or "light" in d:
            view.lights = fmt.lights_from_record(d)
        if "material" in d:
            view.material = fmt.material_from_record(d)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{src}: bad view: {exc}") from None
    if "camera" in d and "width" in d and "height" in d:  # a per-image record: its image size
        view.size = (int(d["width"]), int(d["height"]))
    return view

"""Built-in diverse bodies: anny (parametric MakeHuman body, Apache-2.0 code, CC0 assets)
with a procedural skin texture, a non-skin mask and anatomy labels.

    body = make_body(seed=3)                      # everything sampled from the seed
    body = make_body(seed=3, fitzpatrick=6, pose="arms-down", clothing="shorts")

Frame and units of ``body.mesh``: metres, right-handed, +Y up, the feet standing on
y = 0, the pelvis (anny's root joint) on the Y axis (x = z = 0), the body facing +Z; the
body's own left side is +X. Vertex order, faces and UVs are anny's (13718 vertices,
27420 triangles, MakeHuman's UV layout), so per-vertex data lines up across bodies.

Bodies are cached on disk (compressed npz, atomic writes) under ``cache_dir``
(default ``$GLSYNTH_CACHE`` or ``~/.cache/glsynth``), keyed by a hash of the arguments,
glsynth's and anny's versions and this package's painting code. anny caches its own
model build (~70 s the first time) under ``$ANNY_CACHE_DIR`` or ``~/.cache/anny``;
nothing is downloaded.
"""
from __future__ import annotations

import hashlib
import importlib.metadata
import io
import json
import logging
import os
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from .. import __version__
from ..io.images import write_bytes
from ..mesh import Mesh, SkinSurface
from . import anatomy, chromophores, hairflow, skin
from .colour import fitzpatrick_from_ita, linear_to_srgb, srgb_to_linear

log = logging.getLogger(__name__)

PHENOTYPE_KEYS = ("gender", "age", "muscle", "weight", "height", "proportions")
# Sampling ranges of anny's phenotype parameters (0..1). gender: 0 male .. 1 female;
# age: 0.6..0.95 are adults (anny's anchors: 1/3 child, 2/3 young adult, 1 old).
PHENOTYPE_RANGES = {"age": (0.6, 0.95), "muscle": (0.2, 0.8), "weight": (0.15, 0.85),
                    "height": (0.3, 0.52), "proportions": (0.25, 0.75)}

# Natural poses: bone -> rotation vector in degrees, in the body frame above (X the
# body's left, Y up, Z front), applied at the bone's joint in world-aligned axes. Arms
# are given for the left side and mirrored. "a-pose" is anny's rest pose.
POSES = {
    "a-pose": {},
    "arms-down": {"upperarm01": (0, 0, -36), "lowerarm01": (-8, 0, -4)},
    "arms-raised": {"shoulder01": (0, 0, 22), "upperarm01": (0, 0, 72), "lowerarm01": (0, 0, 10)},
    "slight-turn": {"spine03": (0, 7, 0), "spine01": (0, 7, 0), "neck01": (0, 10, -3),
                    "upperarm01": (0, 0, -24), "lowerarm01": (-10, 0, 0),
                    "upperleg01.R": (-12, 0, 0), "lowerleg01.R": (22, 0, 0),
                    "foot.R": (-10, 0, 0)},
}

# Facial actions (anny's ARKit-style blend shapes, 0..1) that bodies may show. Faces in
# clinical photographs often have their eyes closed (periorbital and eyelid lesions are
# photographed so, and patients shut them against the flash); a closed eye, its lid
# folded over the lash line, is skin.
FACIAL_ACTIONS = ("eyeBlinkLeft", "eyeBlinkRight")
EYES_CLOSED_SHARE, EYES_HALF_SHARE = 0.25, 0.1

# anny (x left, y back, z up) -> body frame (x left, y up, z front)
_TO_BODY = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])


@dataclass
class Body:
    """A textured body. ``mesh.textures["nonskin"]`` is ``nonskin``; ``mesh.vertex_labels``
    is ``anatomy`` (per vertex). ``anatomy_map``: the anatomy labels per texel (uint8,
    texture size; built-in bodies: smooth part borders, see ``anatomy.texel_labels``),
    which views render instead of the per-vertex labels when present. ``nevi``:
    [x0, y0, x1, y1] texel boxes (row 0 = top, x1/y1 exclusive) of the painted moles.
    ``meta``: phenotype, pose, ita, fitzpatrick, seed, clothing, look (hair, eyes...),
    frame."""

    mesh: Mesh
    nonskin: np.ndarray
    anatomy: np.ndarray
    nevi: list
    meta: dict
    anatomy_map: np.ndarray | None = None


def make_body(seed=0, fitzpatrick=None, ita=None, phenotype=None, pose=None, clothing=None,
              texture_size=2048, cache_dir=None, beard=None, expression=None) -> Body:
    """A seeded anny body. Anything not given is sampled from ``seed``: phenotype
    (sex, adult age, muscle, weight, height, proportions), skin tone (Fitzpatrick type
    uniformly, then an ITA inside its band), pose (one of ``POSES``) and clothing.

    fitzpatrick: 1..6; ita: degrees (wins over fitzpatrick, which must then agree);
    phenotype: dict overriding anny parameters (``PHENOTYPE_KEYS``, values 0..1);
    pose: a name in ``POSES``; clothing: see :func:`skin.normalise_clothing`;
    texture_size: texture side in texels (>= 64; 2048 for full detail); beard: a name in
    ``skin.BEARDS`` (default: drawn for adult men); expression: dict of ``FACIAL_ACTIONS``
    coefficients 0..1 (default: drawn by ``sample_expression``; the texture is painted on
    the neutral face).
    """
    args = {"seed": int(seed), "fitzpatrick": fitzpatrick, "ita": ita, "phenotype": phenotype,
            "pose": pose, "clothing": clothing, "texture_size": int(texture_size), "beard": beard,
            "expression": expression}
    _check_args(args)
    key = _cache_key(args)
    path = _cache_path(args, key, cache_dir)
    if path.exists():
        try:
            return _load(path, key, args)
        except Exception as exc:  # a corrupt or foreign file: rebuilt and replaced
            log.warning("body cache %s unusable (%s); rebuilding it", path, exc)
    t0 = time.perf_counter()
    arrays = _build(**args)
    log.info("built body seed=%d in %.1f s", args["seed"], time.perf_counter() - t0)
    _save(path, {**arrays, "cache_key": np.array(key)})
    return _from_arrays(arrays)


def sample_expression(rng: np.random.Generator) -> dict:
    """Eyes closed (``EYES_CLOSED_SHARE``), half closed (``EYES_HALF_SHARE``) or open
    with the lids at rest a little lowered or not."""
    u = rng.random()
    if u < EYES_CLOSED_SHARE:
        blink = 1.0
    elif u < EYES_CLOSED_SHARE + EYES_HALF_SHARE:
        blink = rng.uniform(0.45, 0.75)
    else:
        blink = rng.uniform(0.0, 0.2)
    return {"eyeBlinkLeft": float(blink), "eyeBlinkRight": float(blink)}


def sample_phenotype(rng: np.random.Generator) -> dict:
    female = rng.random() < 0.5
    out = {"gender": float(rng.uniform(0.85, 1.0) if female else rng.uniform(0.0, 0.15))}
    for key, (lo, hi) in PHENOTYPE_RANGES.items():
        out[key] = float(rng.uniform(lo, hi))
    return out


# ---- building -------------------------------------------------------------------------
def _check_args(args):
    if args["fitzpatrick"] is not None and int(args["fitzpatrick"]) not in range(1, 7):
        raise ValueError(f"fitzpatrick must be 1..6, got {args['fitzpatrick']!r}")
    if args["ita"] is not None and not -90 <= float(args["ita"]) <= 90:
        raise ValueError(f"ita must be in [-90, 90] degrees, got {args['ita']!r}")
    if args["ita"] is not None and args["fitzpatrick"] is not None \
            and fitzpatrick_from_ita(float(args["ita"])) != int(args["fitzpatrick"]):
        raise ValueError(f"ita {args['ita']} is not in the band of Fitzpatrick type "
                         f"{args['fitzpatrick']}")
    if args["pose"] is not None and args["pose"] not in POSES:
        raise ValueError(f"unknown pose {args['pose']!r}; choose from {sorted(POSES)}")
    unknown = set(args["expression"] or {}) - set(FACIAL_ACTIONS)
    if unknown:
        raise ValueError(f"unknown facial actions {sorted(unknown)}; use {FACIAL_ACTIONS}")
    bad = {k: v for k, v in (args["expression"] or {}).items() if not 0 <= float(v) <= 1}
    if bad:
        raise ValueError(f"facial action coefficients must be in [0, 1], got {bad}")
    unknown = set(args["phenotype"] or {}) - set(PHENOTYPE_KEYS)
    if unknown:
        raise ValueError(f"unknown phenotype keys {sorted(unknown)}; use {PHENOTYPE_KEYS}")
    if args["texture_size"] < 64:
        raise ValueError(f"texture_size must be >= 64, got {args['texture_size']}")


def _build(seed, fitzpatrick, ita, phenotype, pose, clothing, texture_size, beard,
           expression) -> dict:
    rngs = [np.random.default_rng([seed, k]) for k in range(5)]
    pheno = sample_phenotype(rngs[0])
    pheno.update({k: float(v) for k, v in (phenotype or {}).items()})
    if ita is None:
        fitz = int(fitzpatrick) if fitzpatrick is not None else int(rngs[1].integers(1, 7))
        ita = skin.sample_ita(fitz, rngs[1])
    ita = float(ita)
    fitz = fitzpatrick_from_ita(ita)
    pose = pose if pose is not None else list(POSES)[int(rngs[2].integers(len(POSES)))]
    female = pheno["gender"] > 0.5
    look = skin.sample_look(rngs[3], ita, female, pheno["age"], clothing, beard)
    face = sample_expression(rngs[4])
    face.update({k: float(v) for k, v in (expression or {}).items()})

    st = _static()
    model = _model()
    import torch
    with torch.no_grad():
        rest = model(phenotype_kwargs=pheno)
        posed = model(pose_parameters=_pose_parameters(model, pose), phenotype_kwargs=pheno,
                      facial_actions=face)
    rest_v = rest["rest_vertices"][0].double().numpy() @ _TO_BODY.T
    joints = dict(zip(model.bone_labels, rest["rest_bone_heads"][0].double().numpy() @ _TO_BODY.T))
    v = posed["vertices"][0].double().numpy() @ _TO_BODY.T
    v[:, 1] -= v[:, 1].min()

    hair_coords = hairflow.hair_coordinates(v, st["faces"], st["labels"])
    paint = skin.paint_body(rest_v, st["faces"], st["uvs"], st["face_uvs"], st["scores"],
                            st["labels"], joints, look, size=texture_size,
                            layout=_texel_layout(texture_size),
                            hair_quality=hairflow.hair_flow_quality(v, st["faces"], hair_coords))
    meta = {"seed": seed, "phenotype": pheno, "sex": "female" if female else "male",
            "pose": pose, "expression": face, "ita": ita, "fitzpatrick": fitz, "clothing": look.clothing,
            "look": look.to_dict(), "height_m": float(np.ptp(rest_v[:, 1])),
            "texture_size": texture_size,
            "frame": "metres, +Y up, feet on y=0, pelvis at x=z=0, facing +Z, body's left +X",
            "versions": {"glsynth": __version__, "anny": _anny_version()}}
    meta = json.loads(json.dumps(meta))  # plain JSON types, as after a cache load
    return {"vertices": v, "faces": st["faces"], "uvs": st["uvs"], "face_uvs": st["face_uvs"],
            "texture": paint.texture, "nonskin": paint.nonskin, "features": paint.features,
            "anatomy": st["labels"], "anatomy_map": _anatomy_map(texture_size),
            "nevi": np.asarray(paint.nevi, np.int64).reshape(-1, 4),
            "skin_params": paint.params, "skin_weight": paint.weight, "scalp_hair": paint.scalp_hair,
            "hair_coords": hair_coords,
            "meta": meta}


def hair_curl(look: dict) -> float:
    """The course of scalp hair strands for the shader (SkinSurface.hair_curl): coily
    hair 1, straight hair slightly wavy."""
    return 1.0 if look.get("hair_texture") == "coily" else 0.2


# share of unpigmented strands in scalp hair of each greying colour, and in the body hair
# of the same person: hair greys on the scalp first, on the trunk and limbs years later
SCALP_GREY_SHARE = {"grey": 0.5, "white": 1.0}
BODY_GREY_LAG = 0.4


def body_hair_rgb(look: dict) -> tuple:
    """sRGB of a body's terminal body hair from its look: a little darker and less
    saturated than the scalp hair. Under grey or white scalp hair the body hair is still
    mostly pigmented (dark brown, black on brown and black skin), with BODY_GREY_LAG of
    the scalp's share of white strands mixed in (linear light: the strands' mean). Body
    hair as grey as the scalp drew pale lines across darker skin, read as scratches."""
    scalp = np.asarray(look["hair_rgb"], np.float64)
    name = next((n for n, rgb in skin.HAIR_COLOURS.items() if tuple(rgb) == tuple(scalp)), None)
    if name in SCALP_GREY_SHARE:
        share = BODY_GREY_LAG * SCALP_GREY_SHARE[name]
        pigment = skin.HAIR_COLOURS["black" if look.get("ita", 0.0) < 10 else "dark-brown"]
        mean = (1 - share) * srgb_to_linear(np.divide(pigment, 255)) + share * srgb_to_linear(scalp / 255)
        scalp = 255.0 * linear_to_srgb(mean)
    grey = scalp.mean()
    return tuple(int(round(x)) for x in np.clip(0.85 * (grey + 0.8 * (scalp - grey)), 0, 255))


def _pose_parameters(model, name):
    import roma
    import torch
    out = {}
    for bone, rotvec in POSES[name].items():
        sides = [bone] if bone.endswith((".L", ".R")) or bone.startswith(("spine", "neck")) \
            else [bone + ".L", bone + ".R"]
        for b in sides:
            rv = np.radians(np.asarray(rotvec, float))
            if b.endswith(".R") and not bone.endswith(".R"):
                rv = rv * np.array([1.0, -1.0, -1.0])  # mirror through the x = 0 plane
            R = _TO_BODY.T @ roma.rotvec_to_rotmat(torch.as_tensor(rv)).numpy() @ _TO_BODY
            T = torch.eye(4, dtype=model.dtype)[None].clone()
            T[0, :3, :3] = torch.as_tensor(R, dtype=model.dtype)
            out[b] = T
    return out or None


@lru_cache(maxsize=1)
def _model():
    import anny
    t0 = time.perf_counter()
    # dense torch skinning: no warp kernel build
    model = anny.Anny(skinning_method="lbs", facial_actions=list(FACIAL_ACTIONS))
    log.info("anny model ready in %.1f s", time.perf_counter() - t0)
    return model


def prepare_anny():
    """Build anny's model data once per machine and anny version (its own cache,
    ~/.cache/anny, about 0.8 GB; 1-2 minutes on 2 cores), so that the first run does not
    pay it inside its time: a time-budgeted sim2real run would lose a part to it.
    tools/setup.sh calls this."""
    _model()


@lru_cache(maxsize=1)
def _static() -> dict:
    """Topology, UVs and anatomy of anny's mesh (the same for every body)."""
    import torch
    m = _model()
    faces = m.faces.numpy().astype(np.int64)
    w, idx = m.vertex_bone_weights.numpy(), m.vertex_bone_indices.numpy()
    with torch.no_grad():  # the average body, rest pose: where the trunk is cut
        rest = m()["rest_vertices"][0].double().numpy() @ _TO_BODY.T
    labels, margins = anatomy.anatomy_fields(m.bone_labels, w, idx, faces, rest)
    return {"faces": faces, "uvs": m.texture_coordinates.double().numpy(),
            "face_uvs": m.face_texture_coordinate_indices.numpy().astype(np.int64),
            "scores": anatomy.part_scores(m.bone_labels, w, idx), "labels": labels,
            "margins": margins, "rest": rest}


@lru_cache(maxsize=2)
def _raster(size):
    st = _static()
    return skin.uv_raster(st["uvs"], st["face_uvs"], size)


@lru_cache(maxsize=2)
def _texel_layout(size):
    st = _static()
    return skin.texel_layout(st["uvs"], st["face_uvs"], size, raster=_raster(size))


@lru_cache(maxsize=2)
def _anatomy_map(size):
    """Per-texel anatomy labels (the same for every body: labels are set on the average
    body's rest pose, and the UV layout is anny's)."""
    st = _static()
    return anatomy.texel_labels(st["labels"], st["margins"], st["faces"], *_raster(size))


# ---- cache ----------------------------------------------------------------------------
def _anny_version() -> str:
    try:
        return importlib.metadata.version("anny")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


@lru_cache(maxsize=1)
def _code_hash() -> str:
    """The source of the modules that make a body (the chromophore model included: the
    texture's mottling follows its melanin; not the shader's detail tiles, which no body
    holds: changing them must not rebuild every cached body)."""
    h = hashlib.sha256()
    for mod in (anatomy, chromophores, skin, hairflow):
        h.update(Path(mod.__file__).read_bytes())
    h.update(Path(__file__).read_bytes())
    return h.hexdigest()[:16]


def cache_root(cache_dir=None) -> Path:
    """Where glsynth caches what it derives from assets (bodies, scan skin tones)."""
    return Path(cache_dir or os.environ.get("GLSYNTH_CACHE") or Path.home() / ".cache" / "glsynth")


def _cache_key(args) -> str:
    return json.dumps({"args": args, "glsynth": __version__, "anny": _anny_version(),
                       "code": _code_hash()}, sort_keys=True, default=str)


def _cache_path(args, key, cache_dir):
    root = cache_root(cache_dir)
    digest = hashlib.sha256(key.encode()).hexdigest()[:24]
    return Path(root) / "bodies" / f"body-{args['seed']}-{digest}.npz"


def _save(path: Path, arrays: dict):
    buf = io.BytesIO()
    np.savez_compressed(buf, meta=np.array(json.dumps(arrays["meta"])),
                        **{k: v for k, v in arrays.items() if k != "meta"})
    try:
        write_bytes(path, buf.getbuffer())
    except OSError as exc:
        log.warning("could not cache body at %s: %s", path, exc)


def _load(path: Path, key: str, args: dict) -> Body:
    """The cached body, checked: a file of other arguments (another body's, copied or
    renamed) or with arrays of the wrong shape raises ValueError."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    if "cache_key" not in arrays or str(arrays.pop("cache_key")) != key:
        raise ValueError("written for other arguments (another body's file?)")
    arrays["meta"] = json.loads(str(arrays["meta"]))
    problem = _shape_problem(arrays, args["texture_size"])
    if problem:
        raise ValueError(problem)
    return _from_arrays(arrays)


def _shape_problem(a: dict, size: int):
    """What is wrong with the arrays of a cached body, or None."""
    missing = {"vertices", "faces", "uvs", "face_uvs", "texture", "nonskin", "features",
               "anatomy", "nevi"} - set(a)
    if missing:
        return f"missing arrays {sorted(missing)}"
    v, f, t, ft = a["vertices"], a["faces"], a["uvs"], a["face_uvs"]
    checks = {
        "vertices": v.ndim == 2 and v.shape[1] == 3 and len(v) > 0 and np.isfinite(v).all(),
        "faces": f.ndim == 2 and f.shape[1] == 3 and f.size > 0 and 0 <= f.min() and f.max() < len(v),
        "uvs": t.ndim == 2 and t.shape[1] == 2,
        "face_uvs": ft.shape == f.shape and 0 <= ft.min() and ft.max() < len(t),
        "texture": a["texture"].shape == (size, size, 3) and a["texture"].dtype == np.uint8,
        "nonskin": a["nonskin"].shape[:2] == (size, size),
        "features": a["features"].shape[:2] == (size, size),
        "anatomy": a["anatomy"].shape == (len(v),),
        "nevi": a["nevi"].ndim == 2 and a["nevi"].shape[1] == 4,
        "scalp_hair": "scalp_hair" not in a or a["scalp_hair"].shape == (size, size),
    }
    bad = [k for k, ok in checks.items() if not ok]
    return f"arrays of the wrong shape or content: {', '.join(bad)}" if bad else None


def _from_arrays(a: dict) -> Body:
    meta = a["meta"]
    skin_surface = None
    if "skin_params" in a:
        skin_surface = SkinSurface(a["skin_params"], a["skin_weight"], a["hair_coords"],
                                   body_hair_rgb(meta["look"]),
                                   scalp_hair=a.get("scalp_hair"), hair_curl=hair_curl(meta["look"]))
    mesh = Mesh(a["vertices"], a["faces"], uvs=a["uvs"], face_uvs=a["face_uvs"],
                texture=a["texture"], textures={"nonskin": a["nonskin"], "features": a["features"]},
                vertex_labels=a["anatomy"], name=f"anny-body-{meta['seed']}", skin=skin_surface)
    return Body(mesh=mesh, nonskin=a["nonskin"], anatomy=a["anatomy"],
                nevi=[list(map(int, b)) for b in a["nevi"]], meta=meta, anatomy_map=a["anatomy_map"])

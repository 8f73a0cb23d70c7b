"""Bodies from real scans (3DBodyTex layout, as DermSynth3D uses it) and from any mesh file.

3DBodyTex scan folder (e.g. ``data/3dbodytex/006-f-run``)::

    model_highres_0_normalized.obj   vertices, vt, f v/vt (seams: one vertex, several UVs)
    model_highres_0_normalized.mtl   map_Kd names the texture
    model_highres_0_normalized.png   texture (also the fallback when the MTL names none)
    *nonskin*.png | *non_skin*.png | model_highres_0_normalized_mask.png
                                     non-skin texture mask, 0 skin / 255 non-skin, texture size
    vertslabels_scan.npy             anatomy label 1..16 per OBJ vertex, in file order
    *nevi*.csv | *skin3d*.csv        optional Skin3D nevus boxes in texture pixels

Each file can also be given explicitly. Missing optional parts: no non-skin mask means
all skin (a warning), no anatomy file means ``Body.anatomy = None`` (the pipeline then
writes no anatomy maps), no nevus CSV means no nevi.

Nevus CSV formats (column names case-insensitive; boxes in texels, row 0 = texture top):
Skin3D's own VIA export (``region_shape_attributes`` holding
``{"name": "rect", "x", "y", "width", "height"}``; rows with ``{}`` are skipped), or
columns ``x0,y0,x1,y1`` / ``xmin,ymin,xmax,ymax`` (x1, y1 exclusive), or ``x,y,w,h``
(``width,height`` also accepted). ``Body.nevi`` holds [x0, y0, x1, y1] with x1, y1
exclusive; boxes are clipped to the texture.

Units: 3DBodyTex "normalized" scans are in metres and are kept as they are.
:func:`load_mesh_body` can rescale a generic mesh to a given height.

Frame: glsynth's convention is +Y up. A scan's up axis is its longest extent (a standing
body is taller than it is wide or deep), pointing from the feet to the head when anatomy
labels tell them apart (else along the axis' positive direction); a scan stored with
another up axis is rotated to +Y up, and ``meta["up_axis"]`` / ``meta["rotation"]``
record what was found and applied. ``meta["ita"]`` is the median ITA of the skin
texels (the non-skin mask excluded), as the paper measures skin tone.
"""
from __future__ import annotations

import csv
import json
import logging
import math
import os

import numpy as np

from ..dataformat import N_PARTS
from ..errors import MeshError
from ..io.images import ImageError, read_mask, read_rgb
from ..mesh import Mesh
from .bodies import Body
from .colour import fitzpatrick_from_ita, ita_degrees
from .uv import ensure_uvs

log = logging.getLogger(__name__)

OBJ_NAME = "model_highres_0_normalized.obj"
ANATOMY_NAME = "vertslabels_scan.npy"
_IMAGE_EXT = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class BodyError(MeshError):
    """A scan folder or one of its files is unusable; the message names the file."""


def load_bodytex(folder, nonskin=None, anatomy=None, nevi=None) -> Body:
    """A Body from a 3DBodyTex-layout scan folder (see the module docstring).

    nonskin: path of the non-skin mask; anatomy: path of the per-vertex labels (.npy) or
    an array; nevi: path of a nevus CSV or a list of [x0, y0, x1, y1] boxes.
    """
    folder = os.fspath(folder)
    obj = scan_mesh_path(folder)
    stem = os.path.splitext(obj)[0]

    mesh = Mesh.load(obj, require_texture=False)
    if mesh.uvs is None:
        raise BodyError(f"{obj}: no texture coordinates (vt lines and f v/vt indices)")
    if mesh.texture is None:
        png = stem + ".png"
        if not os.path.isfile(png):
            raise BodyError(f"{obj}: no texture: the material names no map_Kd and "
                            f"{os.path.basename(png)} is not in the folder")
        mesh = mesh.copy_with(texture=_read_rgb(png))
    tex_hw = mesh.texture.shape[:2]

    if nonskin is None:
        nonskin = _find_nonskin(folder, stem)
    if nonskin is None:
        log.warning("%s: no non-skin mask found; treating the whole texture as skin", folder)
        nonskin_map = np.zeros(tex_hw, np.uint8)
    else:
        nonskin_map = read_nonskin(nonskin, tex_hw)

    if anatomy is None and os.path.isfile(os.path.join(folder, ANATOMY_NAME)):
        anatomy = os.path.join(folder, ANATOMY_NAME)
    labels = None if anatomy is None else read_anatomy(anatomy, len(mesh.vertices))
    if labels is None:
        log.info("%s: no %s; anatomy maps will not be available", folder, ANATOMY_NAME)

    if nevi is None:
        nevi = _find_one(folder, ("nevi", "skin3d"), (".csv",))
    boxes = [] if nevi is None else read_nevi(nevi, tex_hw)

    up, rotation = up_axis(mesh.vertices, labels)
    mesh = mesh.copy_with(vertices=mesh.vertices @ rotation.T,
                          textures={**mesh.textures, "nonskin": nonskin_map}, vertex_labels=labels)
    ita = skin_ita(mesh, nonskin_map)
    meta = {"source": "3dbodytex", "id": os.path.basename(os.path.normpath(folder)),
            "mesh_path": obj, "nonskin_path": _path_or_none(nonskin),
            "anatomy_path": _path_or_none(anatomy), "nevi_path": _path_or_none(nevi),
            "units": "metres (3DBodyTex normalized scan, not rescaled)",
            "up_axis": up, "rotation": rotation.tolist(),
            "ita": ita, "fitzpatrick": None if ita is None else fitzpatrick_from_ita(ita),
            "height_m": float(np.ptp(mesh.vertices[:, 1]))}
    return Body(mesh=mesh, nonskin=nonskin_map, anatomy=labels, nevi=boxes, meta=meta)


def scan_mesh_path(folder) -> str:
    """The OBJ of a 3DBodyTex-layout scan folder (BodyError when there is none, or several)."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise BodyError(f"{folder}: scan folder not found")
    obj = os.path.join(folder, OBJ_NAME)
    if not os.path.isfile(obj):
        objs = sorted(n for n in os.listdir(folder) if n.lower().endswith(".obj"))
        if len(objs) != 1:
            raise BodyError(f"{folder}: no {OBJ_NAME} (and {len(objs)} other .obj files)")
        obj = os.path.join(folder, objs[0])
    return obj


_AXES = "xyz"
HEAD, FEET = (1,), (9, 10)


def up_axis(vertices, labels=None) -> tuple[str, np.ndarray]:
    """('+z', R): a body's up axis, the longest extent of its vertices, signed from the
    feet to the head when ``labels`` (1..16 per vertex) hold both, else positive; and
    the rotation R (3x3, det 1) that takes it to +Y (the identity for '+y')."""
    v = np.asarray(vertices, np.float64)
    axis = int(np.argmax(np.ptp(v, axis=0)))
    sign = 1.0
    if labels is not None:
        head, feet = np.isin(labels, HEAD), np.isin(labels, FEET)
        if head.any() and feet.any() and v[head, axis].mean() < v[feet, axis].mean():
            sign = -1.0
    up = np.zeros(3)
    up[axis] = sign
    # the rotation by the shortest arc from `up` to +Y (a half turn about X for -Y)
    y = np.array([0.0, 1.0, 0.0])
    if np.allclose(up, -y):
        rotation = np.diag([1.0, -1.0, -1.0])
    else:
        k = np.cross(up, y)
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        rotation = np.eye(3) + kx + kx @ kx / (1.0 + up @ y)
    return f"{'+' if sign > 0 else '-'}{_AXES[axis]}", np.rint(rotation)


def skin_ita(mesh: Mesh, nonskin) -> float | None:
    """Median ITA (degrees) of the texture at the mesh's UV vertices that lie on skin
    (every texel the surface uses, the unused texture space and the non-skin mask left
    out); None when no UV vertex is on skin."""
    h, w = mesh.texture.shape[:2]
    uv = mesh.uvs[np.unique(mesh.face_uvs)]
    col = np.clip((uv[:, 0] * w).astype(np.int64), 0, w - 1)
    row = np.clip(((1.0 - uv[:, 1]) * h).astype(np.int64), 0, h - 1)
    skin = np.asarray(nonskin)[row, col] == 0
    if not skin.any():
        return None
    return float(np.median(ita_degrees(mesh.texture[row[skin], col[skin]])))


def load_mesh_body(path, nonskin=None, anatomy=None, scale_to_height=None,
                   texture_size=2048) -> Body:
    """A Body from any mesh file (OBJ by glsynth's parser, anything else via trimesh).

    A mesh without UVs gets an xatlas atlas and its vertex colours baked into a
    ``texture_size`` texture (grey without colours); a non-skin mask cannot be given
    then, since no mask can match a freshly made atlas. ``scale_to_height`` (metres):
    scale uniformly about the origin so that the Y extent equals it; otherwise the
    file's units are kept. anatomy: per-vertex labels 1..16 (.npy path or array) in the
    file's vertex order, or None (no anatomy maps).
    """
    path = os.fspath(path)
    mesh = Mesh.load(path, require_texture=False)
    made_uvs = mesh.uvs is None
    if made_uvs and nonskin is not None:
        raise BodyError(f"{path}: has no UVs, so the non-skin mask {os.fspath(nonskin)} "
                        "cannot refer to its texture")
    labels = None if anatomy is None else read_anatomy(anatomy, len(mesh.vertices))
    scale = 1.0 if scale_to_height is None else _height_scale(mesh, float(scale_to_height), path)
    mesh = ensure_uvs(mesh, texture_size)
    if scale != 1.0:
        mesh = mesh.copy_with(vertices=mesh.vertices * scale)
    tex_hw = mesh.texture.shape[:2]
    nonskin_map = (np.zeros(tex_hw, np.uint8) if nonskin is None
                   else read_nonskin(nonskin, tex_hw))
    mesh = mesh.copy_with(textures={**mesh.textures, "nonskin": nonskin_map},
                          vertex_labels=labels)
    meta = {"source": "mesh", "id": os.path.splitext(os.path.basename(path))[0],
            "mesh_path": path, "uvs": "xatlas" if made_uvs else "file", "scale": scale,
            "nonskin_path": _path_or_none(nonskin), "anatomy_path": _path_or_none(anatomy),
            "height": float(np.ptp(mesh.vertices[:, 1]))}
    return Body(mesh=mesh, nonskin=nonskin_map, anatomy=labels, nevi=[], meta=meta)


# ---- the parts ------------------------------------------------------------------------
def read_nonskin(path, texture_hw) -> np.ndarray:
    """uint8 HxW non-skin mask (1 = non-skin) from an image (any non-zero pixel, or the
    alpha channel when it varies), checked against the texture size."""
    path = os.fspath(path)
    try:
        mask = read_mask(path)
    except ImageError as exc:
        raise BodyError(str(exc)) from None
    if mask.shape != tuple(texture_hw):
        raise BodyError(f"{path}: non-skin mask is {mask.shape[1]}x{mask.shape[0]} but the "
                        f"texture is {texture_hw[1]}x{texture_hw[0]}")
    return mask.astype(np.uint8)


def read_anatomy(source, n_vertices: int) -> np.ndarray:
    """uint8 per-vertex anatomy labels 1..16 from an .npy path (float or int) or array."""
    name = os.fspath(source) if isinstance(source, (str, os.PathLike)) else "anatomy labels"
    if isinstance(source, (str, os.PathLike)):
        if not os.path.isfile(name):
            raise BodyError(f"{name}: anatomy label file not found")
        try:
            source = np.load(name, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise BodyError(f"{name}: not a readable .npy array ({exc})") from None
    a = np.asarray(source)
    if a.ndim > 1:
        a = a.squeeze()  # DermSynth3D's files may be (V, 1)
    if a.ndim != 1 or not np.issubdtype(a.dtype, np.number):
        raise BodyError(f"{name}: expected one number per vertex, got {a.dtype} {a.shape}")
    if len(a) != n_vertices:
        raise BodyError(f"{name}: {len(a)} anatomy labels for {n_vertices} mesh vertices")
    f = a.astype(np.float64)
    bad = ~np.isfinite(f) | (f != np.round(f))
    if bad.any():
        i = int(np.argmax(bad))
        raise BodyError(f"{name}: {int(bad.sum())} labels are not whole numbers "
                        f"(vertex {i}: {a[i]!r})")
    bad = (f < 1) | (f > N_PARTS)
    if bad.any():
        i = int(np.argmax(bad))
        raise BodyError(f"{name}: {int(bad.sum())} labels outside 1..{N_PARTS} "
                        f"(vertex {i}: {a[i]!r})")
    return f.astype(np.uint8)


def read_nevi(source, texture_hw) -> list:
    """[[x0, y0, x1, y1], ...] texel boxes (x1, y1 exclusive) from a CSV path (formats in
    the module docstring) or a list of boxes, clipped to the texture."""
    if isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        raw = _nevi_csv(path)
    else:
        path, raw = "nevi", [(i + 1, list(b)) for i, b in enumerate(source)]
    h, w = texture_hw
    boxes = []
    for row, box in raw:
        if len(box) != 4 or not all(isinstance(v, (int, float, np.number)) and math.isfinite(v)
                                    for v in box):
            raise BodyError(f"{path}: row {row}: a box needs 4 finite numbers, got {box!r}")
        x0, y0 = math.floor(box[0]), math.floor(box[1])
        x1, y1 = math.ceil(box[2]), math.ceil(box[3])
        if x1 <= x0 or y1 <= y0:
            raise BodyError(f"{path}: row {row}: empty box {box!r} (x1 <= x0 or y1 <= y0)")
        clipped = [max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)]
        if clipped[2] <= clipped[0] or clipped[3] <= clipped[1]:
            raise BodyError(f"{path}: row {row}: box {box!r} lies outside the {w}x{h} texture")
        if clipped != [x0, y0, x1, y1]:
            log.warning("%s: row %s: box %s clipped to the texture", path, row, box)
        boxes.append(clipped)
    return boxes


_BOX_COLUMNS = ((("x0", "y0", "x1", "y1"), False), (("xmin", "ymin", "xmax", "ymax"), False),
                (("x", "y", "w", "h"), True), (("x", "y", "width", "height"), True))


def _nevi_csv(path) -> list:
    """[(row number, [x0, y0, x1, y1] floats)] from a nevus CSV."""
    if not os.path.isfile(path):
        raise BodyError(f"{path}: nevus CSV not found")
    with open(path, newline="", errors="replace") as fh:
        reader = csv.DictReader(fh)
        cols = {c.strip().lower(): c for c in reader.fieldnames or []}
        rows = list(reader)
    via = "region_shape_attributes" in cols
    fmt = next(((keys, sized) for keys, sized in _BOX_COLUMNS if all(k in cols for k in keys)), None)
    if not via and fmt is None:
        raise BodyError(f"{path}: no box columns; expected region_shape_attributes, "
                        "x0,y0,x1,y1, xmin,ymin,xmax,ymax or x,y,w,h "
                        f"(found {', '.join(cols) or 'none'})")
    out = []
    for i, r in enumerate(rows, start=2):  # row numbers as a spreadsheet shows them
        try:
            if via:
                shape = json.loads(r[cols["region_shape_attributes"]] or "{}")
                if not shape:  # VIA lists images without regions with an empty shape
                    continue
                if shape.get("name") != "rect":
                    raise ValueError(f"unsupported region shape {shape.get('name')!r}")
                a, b, c, d = (float(shape[k]) for k in ("x", "y", "width", "height"))
                sized = True
            else:
                a, b, c, d = (float(r[cols[k]]) for k in fmt[0])
                sized = fmt[1]
        except (ValueError, KeyError, TypeError) as exc:
            raise BodyError(f"{path}: row {i}: unreadable box ({exc})") from None
        out.append((i, [a, b, a + c, b + d] if sized else [a, b, c, d]))
    return out


# ---- helpers --------------------------------------------------------------------------
def _find_nonskin(folder, stem):
    found = _find_one(folder, ("nonskin", "non_skin", "non-skin"), _IMAGE_EXT)
    if found is None and os.path.isfile(stem + "_mask.png"):
        found = stem + "_mask.png"  # the name DermSynth3D's 3DBodyTex masks use
    return found


def _find_one(folder, words, exts):
    names = sorted(n for n in os.listdir(folder)
                   if n.lower().endswith(exts) and any(w in n.lower() for w in words))
    if len(names) > 1:
        raise BodyError(f"{folder}: several candidate files {names}; pass the one to use")
    return os.path.join(folder, names[0]) if names else None


def _read_rgb(path):
    try:
        return read_rgb(path)
    except ImageError as exc:
        raise BodyError(str(exc)) from None


def _height_scale(mesh, height, path) -> float:
    if not (math.isfinite(height) and height > 0):
        raise ValueError(f"scale_to_height must be a positive number of metres, got {height}")
    extent = float(np.ptp(mesh.vertices[:, 1]))
    if extent <= 0:
        raise BodyError(f"{path}: the mesh is flat in Y; cannot scale it to a height")
    return height / extent


def _path_or_none(p):
    return os.fspath(p) if isinstance(p, (str, os.PathLike)) else None

"""Mesh file reading: an OBJ parser that keeps file order and per-face UVs, trimesh for
everything else (GLB, PLY, OFF, STL...)."""
from __future__ import annotations

import os

import numpy as np

from ..errors import MeshError


def load_mesh_arrays(path) -> dict:
    """Read a mesh file into Mesh keyword arguments (texture may be a path)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise MeshError(f"{path}: mesh file not found")
    if path.lower().endswith(".obj"):
        return _read_obj(path)
    return _read_trimesh(path)


def _read_obj(path) -> dict:
    verts, uvs, faces, face_uvs = [], [], [], []
    mtllib = None
    has_uv_faces = True
    with open(path, "r", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            if not line or line[0] == "#":
                continue
            parts = line.split()
            if not parts:
                continue
            key = parts[0]
            try:
                if key == "v":
                    verts.append([float(x) for x in parts[1:4]])
                elif key == "vt":
                    uvs.append([float(x) for x in parts[1:3]])
                elif key == "f":
                    vi, ti = [], []
                    for p in parts[1:]:
                        fields = p.split("/")
                        vi.append(int(fields[0]))
                        if len(fields) > 1 and fields[1]:
                            ti.append(int(fields[1]))
                    if len(vi) < 3:
                        raise ValueError("a face needs at least 3 vertices")
                    if len(ti) != len(vi):
                        has_uv_faces = False
                        ti = [1] * len(vi)
                    # negative indices are relative to the current end of the lists
                    vi = [i - 1 if i > 0 else len(verts) + i for i in vi]
                    ti = [i - 1 if i > 0 else len(uvs) + i for i in ti]
                    for k in range(1, len(vi) - 1):  # fan triangulation of polygons
                        faces.append((vi[0], vi[k], vi[k + 1]))
                        face_uvs.append((ti[0], ti[k], ti[k + 1]))
                elif key == "mtllib" and mtllib is None:
                    mtllib = line.split(None, 1)[1].strip()
            except (ValueError, IndexError) as exc:
                raise MeshError(f"{path}:{lineno}: malformed '{key}' line ({exc}): {line.strip()[:80]}") from None
    if not verts:
        raise MeshError(f"{path}: no vertices")
    if not faces:
        raise MeshError(f"{path}: no faces")
    out = {"vertices": np.array(verts, dtype=np.float64), "faces": np.array(faces, dtype=np.int64)}
    if uvs and has_uv_faces:
        out["uvs"] = np.array(uvs, dtype=np.float64)
        out["face_uvs"] = np.array(face_uvs, dtype=np.int64)
    tex = _texture_from_mtl(path, mtllib) if mtllib else None
    if tex is not None:
        out["texture"] = tex
    return out


def _texture_from_mtl(obj_path, mtllib):
    """Path of the first map_Kd texture in the material library, or None."""
    mtl = os.path.join(os.path.dirname(obj_path), mtllib)
    if not os.path.isfile(mtl):
        raise MeshError(f"{obj_path}: material library {mtllib!r} not found at {mtl}")
    with open(mtl, "r", errors="replace") as fh:
        for line in fh:
            parts = line.strip().split(None, 1)
            if len(parts) == 2 and parts[0].lower() == "map_kd":
                name = parts[1].split()[-1]  # drop options such as -s 1 1 1
                tex = os.path.join(os.path.dirname(mtl), name)
                if not os.path.isfile(tex):
                    raise MeshError(f"{mtl}: texture {name!r} named by map_Kd not found at {tex}")
                return tex
    return None


def _read_trimesh(path) -> dict:
    import trimesh
    try:
        loaded = trimesh.load(path, process=False, maintain_order=True)
    except Exception as exc:
        raise MeshError(f"{path}: trimesh could not read the file ({exc})") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = list(loaded.geometry.values())
        if len(geoms) != 1:
            raise MeshError(f"{path}: scene holds {len(geoms)} meshes; glsynth needs exactly one "
                            "(merge them first)")
        loaded = loaded.to_geometry() if hasattr(loaded, "to_geometry") else geoms[0]
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{path}: not a triangle mesh ({type(loaded).__name__})")
    out = {"vertices": np.asarray(loaded.vertices, dtype=np.float64),
           "faces": np.asarray(loaded.faces, dtype=np.int64)}
    visual = loaded.visual
    uv = getattr(visual, "uv", None)
    if uv is not None and len(uv) == len(out["vertices"]):
        out["uvs"] = np.asarray(uv, dtype=np.float64)
        out["face_uvs"] = out["faces"].copy()
    material = getattr(visual, "material", None)
    image = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
    if image is not None:
        out["texture"] = np.asarray(image.convert("RGB"))
    elif getattr(visual, "kind", None) == "vertex":
        out["vertex_colors"] = np.asarray(visual.vertex_colors)[:, :3]
    return out

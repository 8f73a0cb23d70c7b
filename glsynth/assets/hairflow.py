"""Hair-flow coordinates: a 2D parameterisation of each body part in which body hair
runs along +s, so that the hair tile (glsynth.assets.detail) can be laid on the skin.

Each of the 16 anatomy parts is treated as a cylinder: limbs, hands and feet around
their principal axis (the first principal component of their vertices), oriented away
from the trunk (arm and leg hair points towards the hands and feet); the torso and hips
around the vertical, hair pointing down. A corner's coordinates are ``s`` = distance
along the axis and ``t`` = arc length around it (angle times the part's median radius),
both in scene units, so the tile keeps its physical size. The head is a capsule: below
the centre of the sphere fitted to its upper half, the vertical cylinder of that
sphere's radius; above it, the sphere, where ``s`` is the arc from the crown (the
sphere's top) so that scalp hair falls from the crown and keeps its size over the
skull, where a cylinder stretched it up to several times (its ``t`` still narrows
towards the crown, as meridians do; the shader draws scalp strands at the scale that
``t`` has there, :func:`t_scale_at_corners`). Every face takes the frame of its first
corner's part, and a face across the cylinder's cut has its angles unwrapped, so
coordinates are continuous inside each part; at part borders and along one cut per
part (on the side facing the trunk, or the back) the hair pattern restarts, which at
hair scale reads as nothing in particular.
Where a part's surface turns across its axis (shoulder tops, the crown, fingers) the
cylinder stretches the tile; :func:`hair_flow_quality` finds those places, and body
painting leaves them without hair rather than draw strands several times too long.
"""
from __future__ import annotations

import numpy as np

HEAD = 1
AXIAL_PARTS = (HEAD, 2, 3, 4)   # head, upper and lower torso, hips (glsynth.dataformat)


def _skull_sphere(p):
    """(centre, radius) of the sphere fitted (least squares) to the head vertices p above
    their centroid: the skull and forehead, not the jaw and neck."""
    top = p[p[:, 1] > p[:, 1].mean()]
    if len(top) < 4:
        top = p
    a = np.c_[2 * top, np.ones(len(top))]
    x = np.linalg.lstsq(a, np.sum(top * top, axis=1), rcond=None)[0]
    centre = x[:3]
    return centre, float(np.sqrt(max(x[3] + centre @ centre, 1e-12)))


def _part_frames(vertices, labels):
    """{part: (centre, axis, e1, e2, radius)} for every label > 0 present."""
    v = np.asarray(vertices, np.float64)
    centre_all = v.mean(0)
    up = np.array([0.0, 1.0, 0.0])
    frames = {}
    for k in np.unique(labels):
        if k <= 0:
            continue
        p = v[labels == k]
        if len(p) < 3:
            continue
        c = p.mean(0)
        out = c - centre_all
        out[1] = 0.0                       # horizontal direction from the trunk
        if int(k) in AXIAL_PARTS:
            # head, torso and hips are wider than tall in places (the hips' longest
            # extent runs from side to side): their hair runs down the body regardless
            axis = -up
        else:
            _, _, vt = np.linalg.svd(p - c, full_matrices=False)
            axis = vt[0]
            limb = np.linalg.norm(out) > 0.12 * np.ptp(v[:, 1]) or abs(axis[1]) < 0.5
            if limb and np.linalg.norm(out) > 1e-9:
                if axis @ (c - centre_all) < 0:   # proximal -> distal
                    axis = -axis
            elif axis @ up > 0:                   # a vertical part near the middle: downwards
                axis = -axis
        ref = out if np.linalg.norm(out) > 1e-9 else np.array([0.0, 0.0, 1.0])
        e1 = ref - axis * (ref @ axis)
        if np.linalg.norm(e1) < 1e-9:
            e1 = np.cross(axis, [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        d = p - c
        radial = d - np.outer(d @ axis, axis)
        radius = float(np.median(np.linalg.norm(radial, axis=1)))
        if int(k) == HEAD:
            c, radius = _skull_sphere(p)
        frames[int(k)] = (c, axis, e1, e2, max(radius, 1e-6))
    return frames


def hair_coordinates(vertices, faces, labels) -> np.ndarray:
    """(F, 3, 2) float32 hair-flow coordinates (s along the hair, t across) of every
    face corner; faces of unlabelled parts get 0."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    labels = np.asarray(labels)
    out = np.zeros((len(f), 3, 2), np.float32)
    face_part = labels[f[:, 0]]
    for k, (c, axis, e1, e2, radius) in _part_frames(v, labels).items():
        sel = np.flatnonzero(face_part == k)
        d = v[f[sel]] - c                                   # n x 3 x 3
        s = d @ axis
        if k == HEAD:   # the skull's cap: the arc from the crown, meeting the cylinder's s
            above = s < 0
            polar = np.arctan2(np.hypot(d[..., 0], d[..., 2]), d[..., 1])
            s = np.where(above, radius * polar, radius * np.pi / 2 + s)
        phi = np.arctan2(d @ e2, d @ e1)
        # unwrap faces across the cut at phi = +-pi
        span = phi.max(1) - phi.min(1)
        cut = span > np.pi
        phi[cut] = np.where(phi[cut] < 0, phi[cut] + 2 * np.pi, phi[cut])
        out[sel, :, 0] = s
        out[sel, :, 1] = phi * radius
    return out


def hair_flow_quality(vertices, faces, coords, lo=1.6, hi=2.6) -> np.ndarray:
    """(V,) float32 in [0, 1]: how faithfully the hair-flow coordinates lay the hair tile
    near each vertex. A part treated as a cylinder stretches the tile where its surface
    turns across the axis (shoulder tops, the crown, the backs of hands and feet): a
    coordinate unit there covers several times its length of skin, and hair strands
    would be drawn that much longer. Per face, the larger singular value of dp/d(s, t)
    (and the inverse of the smaller one) is that stretch; 1 below ``lo``, 0 above ``hi``,
    worst face around each vertex. Body painting fades hair out where it is low."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    jac, ok, degenerate = _surface_per_coordinate(v, f, coords)
    stretch = np.full(len(f), np.inf)
    sv = np.linalg.svd(jac[ok], compute_uv=False)
    stretch[ok] = np.maximum(sv[:, 0], 1.0 / np.maximum(sv[:, 1], 1e-12))
    stretch[degenerate] = 1.0                 # degenerate faces show nothing anyway
    worst = np.zeros(len(v))
    np.maximum.at(worst, f.ravel(), np.repeat(stretch, 3))
    x = np.clip((hi - worst) / (hi - lo), 0.0, 1.0)
    return (x * x * (3 - 2 * x)).astype(np.float32)


def t_scale_at_corners(vertices, faces, coords) -> np.ndarray:
    """(F, 3) float32: at each face corner, the surface that a unit of t covers there
    (|dp/dt|), averaged over the faces round the corner's vertex so that it varies
    smoothly across faces (per face it jumps at every edge). The shader draws scalp
    strands at t's local scale with it (skin.frag scalp_hair); 1 where no face tells."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    jac, ok, _ = _surface_per_coordinate(v, f, coords)
    lt = np.linalg.norm(jac[ok][..., 1], axis=-1)
    total, count = np.zeros(len(v)), np.zeros(len(v))
    np.add.at(total, f[ok].ravel(), np.repeat(lt, 3))
    np.add.at(count, f[ok].ravel(), 1.0)
    per_vertex = np.where(count > 0, total / np.maximum(count, 1.0), 1.0)
    return per_vertex[f].astype(np.float32)


def _surface_per_coordinate(v, f, coords):
    """Per face, dp/d(s, t) (F x 3 x 2: the 3D edges times the inverse of the coordinate
    edges; zero where not ``ok``), which faces have it, and which are degenerate."""
    h = np.asarray(coords, np.float64)
    e = np.stack([v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]], -1)      # F x 3 x 2
    hh = np.stack([h[:, 1] - h[:, 0], h[:, 2] - h[:, 0]], -1)                 # F x 2 x 2
    det = hh[:, 0, 0] * hh[:, 1, 1] - hh[:, 0, 1] * hh[:, 1, 0]
    area = np.linalg.norm(np.cross(e[..., 0], e[..., 1]), axis=1)
    ok = (np.abs(det) > 1e-14) & (area > 1e-14)
    jac = np.zeros((len(f), 3, 2))
    jac[ok] = e[ok] @ np.linalg.inv(hh[ok])
    return jac, ok, area <= 1e-14

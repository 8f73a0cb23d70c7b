"""Hair-flow coordinates: a 2D parameterisation of each body part in which body hair
runs along +s, so that the hair tile (glsynth.assets.detail) can be laid on the skin.

Each of the 16 anatomy parts is treated as a cylinder around its principal axis (the
first principal component of its vertices), oriented away from the trunk on limbs
(arm and leg hair points towards the hands and feet) and downwards on the head and
trunk. A corner's coordinates are ``s`` = distance along the axis and ``t`` = arc length
around it (angle times the part's median radius), both in scene units, so the tile keeps
its physical size. Every face takes the frame of its first corner's part, and a face
across the cylinder's cut has its angles unwrapped, so coordinates are continuous inside
each part; at part borders and along one cut per part (on the side facing the trunk, or
the back) the hair pattern restarts, which at hair scale reads as nothing in particular.
"""
from __future__ import annotations

import numpy as np


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
        _, _, vt = np.linalg.svd(p - c, full_matrices=False)
        axis = vt[0]
        out = c - centre_all
        out[1] = 0.0                       # horizontal direction from the trunk
        limb = np.linalg.norm(out) > 0.12 * np.ptp(v[:, 1]) or abs(axis[1]) < 0.5
        if limb and np.linalg.norm(out) > 1e-9:
            if axis @ (c - centre_all) < 0:   # proximal -> distal
                axis = -axis
        elif axis @ up > 0:                   # head, trunk: downwards
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
        phi = np.arctan2(d @ e2, d @ e1)
        # unwrap faces across the cut at phi = +-pi
        span = phi.max(1) - phi.min(1)
        cut = span > np.pi
        phi[cut] = np.where(phi[cut] < 0, phi[cut] + 2 * np.pi, phi[cut])
        out[sel, :, 0] = s
        out[sel, :, 1] = phi * radius
    return out

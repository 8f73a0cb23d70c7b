"""Perspective cameras (OpenGL convention: the camera looks down -Z in view space, +Y up).

Image convention: pixel (row, col) has its centre at ((col + 0.5), (row + 0.5)) with row 0
at the *top* of the image.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_UP_FALLBACKS = ((0.0, 1.0, 0.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0))


def _unit(v, what):
    v = np.asarray(v, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{what} must be finite, got {v.tolist()}")
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        raise ValueError(f"{what} must be non-zero, got {v.tolist()}")
    return v / n


@dataclass(frozen=True)
class Camera:
    """A pinhole camera. ``eye``/``target``/``up`` in scene units, ``fov_deg`` vertical.

    ``near``/``far`` may be left as None: the renderer then chooses them from the mesh
    (see ``Camera.clip_planes``).
    """

    eye: tuple
    target: tuple
    up: tuple = (0.0, 1.0, 0.0)
    fov_deg: float = 30.0
    width: int = 512
    height: int = 512
    near: float | None = None
    far: float | None = None
    # Extra description kept for the dataset's JSON (surface point, normal, w).
    surface: dict | None = None
    # (x0, y0, full_width, full_height): this camera renders the width x height
    # sub-rectangle at (x0, y0) of a full_width x full_height image (see ``crop``).
    window: tuple | None = None

    # ---- construction -------------------------------------------------------------
    @classmethod
    def look_at(cls, eye, target, up=(0.0, 0.0 + 1.0, 0.0), fov_deg=30.0, width=512,
                height=512, near=None, far=None):
        eye = np.asarray(eye, dtype=np.float64).reshape(3)
        target = np.asarray(target, dtype=np.float64).reshape(3)
        forward = _unit(target - eye, "look-at direction (target - eye)")
        up = _valid_up(forward, up)
        if not (0.0 < fov_deg < 180.0):
            raise ValueError(f"fov_deg must be in (0, 180), got {fov_deg}")
        if int(width) < 1 or int(height) < 1:
            raise ValueError(f"image size must be positive, got {width}x{height}")
        return cls(tuple(eye.tolist()), tuple(target.tolist()), tuple(up.tolist()),
                   float(fov_deg), int(width), int(height), near, far)

    @classmethod
    def from_surface(cls, point, normal, w, fov_deg=30.0, width=512, height=512, up=None):
        """Eye at ``point + normal * w`` looking at ``point`` (DermSynth3D Eq. 2).

        The up vector is +Y unless the normal is (nearly) parallel to it, in which case
        -Z is used, so the camera is defined for every normal.
        """
        point = np.asarray(point, dtype=np.float64).reshape(3)
        n = _unit(normal, "surface normal")
        if not (np.isfinite(w) and w > 0):
            raise ValueError(f"camera distance weight w must be > 0, got {w}")
        cam = cls.look_at(point + n * w, point, up=(0.0, 1.0, 0.0) if up is None else up,
                          fov_deg=fov_deg, width=width, height=height)
        surface = {"point": point.tolist(), "normal": n.tolist(), "w": float(w)}
        return cls(cam.eye, cam.target, cam.up, cam.fov_deg, cam.width, cam.height,
                   None, None, surface)

    # ---- matrices -----------------------------------------------------------------
    @property
    def aspect(self) -> float:
        return self.width / self.height

    def crop(self, x0, y0, width, height) -> "Camera":
        """The same view restricted to pixels [y0, y0+height) x [x0, x0+width): an
        off-axis camera, so only that region is rasterised."""
        fx0, fy0, fw, fh = self.window or (0, 0, self.width, self.height)
        return Camera(self.eye, self.target, self.up, self.fov_deg, int(width), int(height),
                      self.near, self.far, self.surface, (fx0 + int(x0), fy0 + int(y0), fw, fh))

    def view_matrix(self) -> np.ndarray:
        """4x4 world-to-view matrix (float64)."""
        eye = np.asarray(self.eye)
        f = _unit(np.asarray(self.target) - eye, "view direction")
        s = _unit(np.cross(f, self.up), "camera right vector")
        u = np.cross(s, f)
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = s, u, -f
        m[:3, 3] = -m[:3, :3] @ eye
        return m

    def projection_matrix(self, near=None, far=None) -> np.ndarray:
        """4x4 OpenGL projection (clip z in [-w, w]) for the given or stored planes,
        built from ``intrinsics`` so that cropped (off-axis) cameras work too."""
        near = self.near if near is None else near
        far = self.far if far is None else far
        if near is None or far is None:
            raise ValueError("near/far not set: pass them or use Camera.clip_planes")
        if not (0 < near < far):
            raise ValueError(f"need 0 < near < far, got near={near} far={far}")
        k = self.intrinsics()
        w, h = self.width, self.height
        p = np.zeros((4, 4))
        p[0, 0] = 2 * k[0, 0] / w
        p[0, 2] = 1 - 2 * k[0, 2] / w
        p[1, 1] = 2 * k[1, 1] / h
        p[1, 2] = 2 * k[1, 2] / h - 1
        p[2, 2] = -(far + near) / (far - near)
        p[2, 3] = -2 * far * near / (far - near)
        p[3, 2] = -1.0
        return p

    def intrinsics(self) -> np.ndarray:
        """3x3 pinhole matrix K in pixels (row 0 at the top, pixel centres at +0.5)."""
        x0, y0, fw, fh = self.window or (0, 0, self.width, self.height)
        f = fh / 2 / math.tan(math.radians(self.fov_deg) / 2)
        return np.array([[f, 0.0, fw / 2 - x0], [0.0, f, fh / 2 - y0], [0, 0, 1.0]])

    def clip_planes(self, bounds_min, bounds_max, vertices=None, distance=None):
        """Near/far planes that keep depth precise for this camera and scene.

        far: the farthest corner of the scene's bounding box (x1.01).
        near: half the distance to the scene: ``distance`` when the caller knows it
        exactly (``Mesh.distance_to``: the renderer passes it), else the closest of the
        look-at point, the bounding box and the ``vertices`` (a face can come nearer
        than all its corners). Triangles that still reach in front of the near plane
        are not clipped: the renderer enables depth clamping, and G-buffer depth values
        come from the exact view-space z, not the z-buffer.
        The near/far ratio stays <= 1e5, which a 24-bit z-buffer resolves from
        w = 0.005 to w = 100 on metre-scale bodies; a camera closer than 5e-6 of the far
        distance (~0.01 mm for a body) raises ValueError instead of losing pixels.
        """
        eye = np.asarray(self.eye)
        lo, hi = np.asarray(bounds_min, float), np.asarray(bounds_max, float)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])])
        far = float(np.linalg.norm(corners - eye, axis=1).max()) * 1.01 + 1e-9
        if distance is not None:
            closest = float(distance)
        else:
            closest = float(np.linalg.norm(np.asarray(self.target) - eye))
            box_gap = float(np.linalg.norm(np.maximum(0, np.maximum(lo - eye, eye - hi))))
            if box_gap > 0:
                closest = min(closest, box_gap)
            if vertices is not None and len(vertices):
                closest = min(closest, float(np.sqrt(((vertices - eye) ** 2).sum(1).min())))
        if closest < far * 5e-6:
            raise ValueError(
                f"camera is {closest:.3g} from the surface, below 5e-6 of the scene's depth "
                f"range ({far:.3g}): the z-buffer cannot resolve it; move the camera away "
                f"(e.g. w >= {far * 5e-6:.2g})")
        near = max(closest * 0.5, far * 1e-5)
        return near, max(far, near * 2)

    # ---- export -------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {"eye": list(self.eye), "target": list(self.target), "up": list(self.up),
             "fov_deg": self.fov_deg, "width": self.width, "height": self.height}
        if self.window is not None:
            d["window"] = list(self.window)
        if self.surface is not None:
            d.update(self.surface)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        cam = cls.look_at(d["eye"], d["target"], d.get("up", (0, 1, 0)),
                          d.get("fov_deg", 30.0), d.get("width", 512), d.get("height", 512))
        if "point" in d:
            surface = {k: d[k] for k in ("point", "normal", "w") if k in d}
            return cls(cam.eye, cam.target, cam.up, cam.fov_deg, cam.width, cam.height,
                       None, None, surface)
        return cam

    def with_size(self, width, height) -> "Camera":
        if self.window is not None:
            raise ValueError("a cropped camera keeps its own size")
        return Camera(self.eye, self.target, self.up, self.fov_deg, int(width), int(height),
                      self.near, self.far, self.surface)

    def project(self, points) -> np.ndarray:
        """Project world points (N,3) to pixel coordinates (N,2) as (x=col, y=row)."""
        p = np.c_[np.asarray(points, float), np.ones(len(points))] @ self.view_matrix().T
        k = self.intrinsics()
        z = -p[:, 2]
        x = k[0, 0] * p[:, 0] / z + k[0, 2]
        y = -k[1, 1] * p[:, 1] / z + k[1, 2]
        return np.stack([x, y], 1)

    def pixel_rays(self, rows, cols):
        """World-space ray origins and unit directions through pixel centres."""
        k = self.intrinsics()
        x = (np.asarray(cols, float) + 0.5 - k[0, 2]) / k[0, 0]
        y = -(np.asarray(rows, float) + 0.5 - k[1, 2]) / k[1, 1]
        d_view = np.stack([x, y, -np.ones_like(x)], -1)
        rot = self.view_matrix()[:3, :3].T
        d = d_view @ rot.T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return np.broadcast_to(np.asarray(self.eye), d.shape).copy(), d


def _valid_up(forward, up):
    """An up vector not parallel to ``forward`` (the requested one when possible)."""
    for cand in ((up,) + _UP_FALLBACKS):
        u = np.asarray(cand, dtype=np.float64)
        if np.linalg.norm(np.cross(forward, u)) > 1e-6 * max(np.linalg.norm(u), 1e-300):
            return u / np.linalg.norm(u)
    raise AssertionError("unreachable: three orthogonal fallbacks")

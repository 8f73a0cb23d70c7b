"""Camera moves of the previewer: a whole-body start view, orbit, zoom and pan."""
from __future__ import annotations

import math

import numpy as np

from ..camera import Camera


def overview_camera(mesh, width, height, fov_deg=30.0) -> Camera:
    """The whole mesh from the front (+Z for built-in bodies), filling the window."""
    lo, hi = (np.asarray(b, float) for b in mesh.bounds)
    centre, ext = (lo + hi) / 2, hi - lo
    half = max(ext[1] / 2, ext[0] / 2 * height / width, 1e-6)
    dist = half / math.tan(math.radians(fov_deg) / 2) * 1.15 + ext[2] / 2
    return Camera.look_at(centre + np.array([0.0, 0.0, dist]), centre, fov_deg=fov_deg,
                          width=width, height=height)


def _rotate(v, axis, angle):
    """Rodrigues rotation of v about the unit axis."""
    axis = axis / np.linalg.norm(axis)
    c, s = math.cos(angle), math.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * np.dot(axis, v) * (1 - c)


def orbit(cam, d_yaw, d_pitch) -> Camera:
    """Turn the eye about the target: yaw about the camera's up vector, pitch about its
    right vector (stopping short of the poles)."""
    eye, target, up = (np.asarray(v, float) for v in (cam.eye, cam.target, cam.up))
    off = _rotate(eye - target, up, d_yaw)
    right = np.cross(target - (target + off), up)
    if np.linalg.norm(right) > 1e-9 and d_pitch:
        new = _rotate(off, right, d_pitch)
        if abs(np.dot(new / np.linalg.norm(new), up / np.linalg.norm(up))) < 0.995:
            off = new
    return Camera.look_at(target + off, target, up, cam.fov_deg, cam.width, cam.height)


def zoom(cam, factor) -> Camera:
    """The eye moved along the view axis to ``factor`` times its distance."""
    eye, target = np.asarray(cam.eye, float), np.asarray(cam.target, float)
    off = (eye - target) * factor
    if np.linalg.norm(off) < 1e-4:
        return cam
    return Camera.look_at(target + off, target, cam.up, cam.fov_deg, cam.width, cam.height)


def pan(cam, dx_px, dy_px) -> Camera:
    """Move eye and target together so the scene follows the mouse by (dx, dy) pixels
    at the target's distance."""
    eye, target = np.asarray(cam.eye, float), np.asarray(cam.target, float)
    view = cam.view_matrix()
    right, up = view[0, :3], view[1, :3]
    dist = np.linalg.norm(target - eye)
    per_px = 2 * dist * math.tan(math.radians(cam.fov_deg) / 2) / cam.height
    shift = (-dx_px * right + dy_px * up) * per_px
    return Camera.look_at(eye + shift, target + shift, cam.up, cam.fov_deg, cam.width, cam.height)


def follow(point, old_cam, new_cam) -> np.ndarray:
    """``point`` moved with the camera: the same offset in the new camera's frame (right,
    up, back) as in the old one's. The previewer's light follows the camera this way."""
    if (old_cam.eye, old_cam.target, old_cam.up) == (new_cam.eye, new_cam.target, new_cam.up):
        return np.asarray(point, float)  # the same view (resized): exactly where it was
    old, new = old_cam.view_matrix()[:3, :3], new_cam.view_matrix()[:3, :3]
    offset = old @ (np.asarray(point, float) - np.asarray(old_cam.eye, float))
    return np.asarray(new_cam.eye, float) + new.T @ offset

"""Pinhole camera model: look-at poses, OpenCV intrinsics/extrinsics, and the 2D goal projection
(docs/study.md, 2D goal projection)."""

from __future__ import annotations

import numpy as np

WORLD_UP = np.array([0.0, 0.0, 1.0])


def intrinsic_from_fov(width: int, fov_deg: float) -> np.ndarray:
    """3x3 OpenCV intrinsics of a square image with horizontal FOV ``fov_deg`` (fx = W/2 at 90 degrees)."""
    f = (width / 2.0) / np.tan(np.deg2rad(fov_deg) / 2.0)
    c = width / 2.0
    return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])


def extrinsic_look_at(eye, target, up=WORLD_UP) -> np.ndarray:
    """3x4 world-to-camera [R | t] in OpenCV convention (x right, y down, z forward) for a camera at ``eye``
    looking at ``target``."""
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    norm = np.linalg.norm(forward)
    if norm == 0:
        raise ValueError(f"camera eye and target coincide at {eye.tolist()}")
    forward /= norm
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("camera looks straight along the up axis; the look-at pose is undefined")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rot = np.stack([right, down, forward])
    return np.concatenate([rot, (-rot @ eye)[:, None]], axis=1)


def project_points(points: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray) -> np.ndarray:
    """Project world points (..., 3) to pixel coordinates (..., 2) (u right, v down; pixel centres at +0.5).

    ``intrinsic`` (3, 3) or batched (..., 3, 3) and ``extrinsic`` (3, 4) or (..., 3, 4) broadcast with points."""
    points = np.asarray(points, dtype=np.float64)
    rot, trans = extrinsic[..., :3], extrinsic[..., 3]
    cam = np.einsum("...ij,...j->...i", rot, points) + trans
    z = cam[..., 2]
    pix = np.einsum("...ij,...j->...i", intrinsic, cam)
    # Points behind the camera have no image; push them far outside so clipping pins them to an edge.
    safe_z = np.where(z > 1e-9, z, 1e-9)
    return pix[..., :2] / safe_z[..., None]


def goal2d(points: np.ndarray, intrinsics: np.ndarray, extrinsics: np.ndarray, width: int) -> np.ndarray:
    """The normalized 2D goal (docs/study.md, 2D goal projection): for each camera c, (u, v) clipped to the image
    and divided by W, concatenated over cameras -> (..., 2 * C) in [0, 1].

    points (N, 3); intrinsics (C, 3, 3) or (N, C, 3, 3); extrinsics (C, 3, 4) or (N, C, 3, 4)."""
    points = np.asarray(points, dtype=np.float64)
    uv = project_points(points[:, None, :], intrinsics, extrinsics)  # (N, C, 2)
    uv = np.clip(uv, 0.0, float(width)) / float(width)
    return uv.reshape(len(points), -1)

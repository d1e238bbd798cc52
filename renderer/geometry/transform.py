"""Host-side transforms of scene placement (``rotate`` on boxes and meshes): used by the scene
compiler and by ``auto``'s bounding spheres, so that neither imports the other for it."""

from __future__ import annotations

import math

import numpy as np


def rotation_matrix(axis, angle_degrees: float) -> np.ndarray:
    """Right-handed rotation about ``axis`` through the origin (Rodrigues' formula)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    a = math.radians(angle_degrees)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(a) * kx + (1 - math.cos(a)) * (kx @ kx)


def placement(scale, rotate, translate) -> tuple[np.ndarray, np.ndarray]:
    """(M, t) of a mesh's placement: x ↦ M·x + t scales (a number or one per axis), then rotates
    (``rotate``: axis and angle in degrees, about the world origin), then translates, as the scene
    format orders them; None for any part leaves it out."""
    m = np.diag(np.broadcast_to(np.asarray(1.0 if scale is None else scale, np.float64), (3,)))
    if rotate is not None:
        m = rotation_matrix(rotate.axis, rotate.angle) @ m
    t = np.zeros(3) if translate is None else np.asarray(translate, dtype=np.float64)
    return m, t

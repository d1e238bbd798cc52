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

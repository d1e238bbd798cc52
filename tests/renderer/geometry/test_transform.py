"""``renderer.geometry.transform``: the placement's linear map applied to many points without a
matrix product (``apply_linear``), against the product it stands for."""

from __future__ import annotations

import numpy as np

from renderer.geometry.transform import apply_linear, placement, rotation_matrix


def test_apply_linear_is_the_matrix_product_of_the_transpose():
    """points @ m.T, to rounding, for a general 3×3 (not symmetric, so a transposed reading
    fails) and a placement's; each row is m times the point (a rotation about z by 90° turns
    x into y)."""
    rng = np.random.default_rng(5)
    points = rng.normal(size=(1000, 3)) * 10.0 ** rng.integers(-6, 6, (1000, 1))
    for m in (rng.normal(size=(3, 3)), placement([2.0, 1.0, 0.5], None, None)[0]):
        # (within a dot product's rounding of three terms, where they may cancel)
        bound = 1e-15 * (np.abs(points) @ np.abs(m).T)
        assert (np.abs(apply_linear(points, m) - points @ m.T) <= bound).all()
    turn = rotation_matrix([0, 0, 1], 90.0)
    np.testing.assert_allclose(apply_linear(np.array([[1.0, 0.0, 0.0]]), turn), [[0, 1, 0]],
                               atol=1e-15)
    assert apply_linear(np.zeros((0, 3)), turn).shape == (0, 3)

"""bench.equal_error's reading of a ladder: the time at which a renderer reaches a target error."""

from __future__ import annotations

import math

import pytest

from bench.equal_error import time_to_error


def test_an_unbiased_ladder_is_read_exactly():
    # error = 1/time (an unbiased estimator): the target 0.02 is reached at 50 s, between rungs
    points = [(t, 1.0 / t) for t in (10.0, 40.0, 160.0)]
    assert time_to_error(points, 0.02) == pytest.approx(50.0, rel=1e-12)


def test_below_the_first_rung_is_extrapolated_as_one_over_time():
    assert time_to_error([(2.0, 0.01), (8.0, 0.0025)], 0.04) == pytest.approx(0.5)


def test_a_target_below_a_bias_floor_is_never_reached():
    assert time_to_error([(1.0, 0.5), (4.0, 0.3), (16.0, 0.3)], 0.1) is None


def test_a_rung_exactly_at_the_target():
    assert math.isclose(time_to_error([(1.0, 0.5), (4.0, 0.1)], 0.1), 4.0)

import numpy as np
import pytest

from guardrail_core.errors import ReconstructionError
from guardrail_core.reconstruct.pipes.consensus import confirmed_by_another_unit


def test_a_point_is_confirmed_by_another_units_point_in_its_cube_or_the_next():
    points = np.array(
        [
            [0.000, 0.0, 0.0],  # unit 0, with unit 1 one cell away
            [0.025, 0.0, 0.0],  # unit 1
            [0.500, 0.0, 0.0],  # unit 0, with only unit 0 near
            [0.505, 0.0, 0.0],  # unit 0
            [1.000, 0.0, 0.0],  # unit 2, with unit 3 three cells away
            [1.065, 0.0, 0.0],  # unit 3
            [2.000, 0.0, 0.0],  # unit 4, and a cell shared by units 5 and 6 next to it
            [2.021, 0.0, 0.0],  # unit 5
            [2.022, 0.0, 0.0],  # unit 6
        ]
    )
    unit = np.array([0, 1, 0, 0, 2, 3, 4, 5, 6])
    confirmed = confirmed_by_another_unit(points, unit, 0.02)
    assert confirmed.tolist() == [True, True, False, False, False, False, True, True, True]


def test_the_three_axes_count_alike():
    base = np.zeros((1, 3))
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = 0.03
        near = confirmed_by_another_unit(np.vstack([base, base + step]), np.array([0, 1]), 0.02)
        far = confirmed_by_another_unit(np.vstack([base, base + 3 * step]), np.array([0, 1]), 0.02)
        assert near.tolist() == [True, True] and far.tolist() == [False, False]


def test_no_points_and_bad_input():
    assert confirmed_by_another_unit(np.zeros((0, 3)), np.zeros(0, int), 0.02).shape == (0,)
    with pytest.raises(ReconstructionError, match="one unit per point"):
        confirmed_by_another_unit(np.zeros((3, 3)), np.zeros(2, int), 0.02)
    with pytest.raises(ReconstructionError, match="positive"):
        confirmed_by_another_unit(np.zeros((3, 3)), np.zeros(3, int), 0.0)
    with pytest.raises(ReconstructionError, match="too many cells"):
        confirmed_by_another_unit(np.array([[0.0, 0, 0], [1e5, 0, 0]]), np.array([0, 1]), 0.02)

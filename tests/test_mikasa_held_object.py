"""``HeldCube``: a camera-only expert's cube, seen once, gripped, carried at its grip and let go where it was."""

import numpy as np

from sb3_memret.tasks.mikasa.core.carry_expert import CarryGains
from sb3_memret.tasks.mikasa.core.held_object import HeldCube


def test_the_cube_is_gripped_only_within_reach_carried_at_its_grip_and_left_where_it_was_let_go():
    carry = CarryGains()
    cube = HeldCube(carry)
    cube.reset(2)
    cube.see(0, np.array([0.1, 0.0, 0.02]))
    cube.see(0, np.array([9.0, 9.0, 9.0]))  # placed already: a later sighting does not move it
    assert np.allclose(cube.places[0], [0.1, 0.0, 0.02]) and cube.places[1] is None
    closed = float(np.mean(carry.held_gap))
    far = np.array([0.1, 0.1, 0.02])  # the fingers closed 10 cm away: not on this cube
    assert np.allclose(cube.track(0, far, closed), [0.1, 0.0, 0.02]) and cube.grips[0] is None
    at = np.array([0.105, 0.0, 0.025])  # within reach: gripped at an offset of (0.5, 0, 0.5) cm
    cube.track(0, at, closed)
    assert np.allclose(cube.grips[0], [0.005, 0.0, 0.005])
    assert np.allclose(cube.track(0, at + [0.0, 0.2, 0.1], closed), [0.1, 0.2, 0.12])  # carried with the hand
    assert np.allclose(cube.track(0, at + [0.0, 0.3, 0.1], 0.0), [0.1, 0.2, 0.12])  # shut on nothing: let go
    assert cube.grips[0] is None
    cube.reset_env(0)
    assert cube.places[0] is None and cube.grips[0] is None

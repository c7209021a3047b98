"""Each camera draws only the bodies it can see: the frustum tests, and the same pictures bit for bit on a MIKASA
scene whose wrist camera never sees its own mount."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING
from sb3_memret.physics.frustum_cull import FrustumCull, boxes_outside, cullable, mesh_outside, outside_planes

# an OpenGL perspective projection (90 degree field of view, near 0.1, far 10), the camera at the origin looking -z
NEAR, FAR = 0.1, 10.0
PROJECTION = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0],
                       [0, 0, -(FAR + NEAR) / (FAR - NEAR), -2 * FAR * NEAR / (FAR - NEAR)], [0, 0, -1.0, 0]])


def clip(points) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    return np.hstack([points, np.ones((len(points), 1))]) @ PROJECTION.T


def box(low, high) -> np.ndarray:
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
    return clip(low + corners * (high - low))


def test_each_point_names_the_planes_it_lies_outside():
    masks = outside_planes(clip([[0, 0, -1], [-5, 0, -1], [5, 0, -1], [0, 0, 1], [0, 0, -20]]))
    assert masks[0] == 0  # in view
    assert masks[1] & 1 and masks[2] & 2  # left of the left plane, right of the right one
    assert masks[3] & 16 and masks[4] & 32  # behind the near plane, beyond the far one


def test_a_box_is_culled_only_when_wholly_outside_one_plane():
    boxes = {
        "in front": ([-0.5, -0.5, -2], [0.5, 0.5, -1]),
        "across the left plane": ([-5, -0.5, -2], [0.5, 0.5, -1]),
        "around the camera": ([-1, -1, -1], [1, 1, 1]),
        # outside the left and the top plane together but wholly outside neither: kept (conservative)
        "in the left-top corner region": ([-8, -0.5, -2], [-1.5, 8, -1.9]),
        "behind": ([-0.5, -0.5, 1], [0.5, 0.5, 2]),
        "to the right": ([5, -0.5, -2], [6, 0.5, -1]),
        "beyond the far plane": ([-0.5, -0.5, -30], [0.5, 0.5, -20]),
    }
    culled = boxes_outside(np.stack([box(*corners) for corners in boxes.values()]))
    assert dict(zip(boxes, culled.tolist())) == {name: name in ("behind", "to the right", "beyond the far plane")
                                                 for name in boxes}


def test_a_mesh_is_culled_only_when_every_triangle_lies_outside_one_plane():
    behind = clip([[0, 0, 1], [1, 0, 1], [0, 1, 1]])
    assert mesh_outside(behind, np.array([[0, 1, 2]]))
    # a triangle whose corners are each outside a plane, left and right, crosses the view in front
    across = clip([[-5, 0, -1], [5, 0, -1], [0, 0.1, -1]])
    assert not mesh_outside(across, np.array([[0, 1, 2]]))
    both = np.vstack([behind, across])
    assert not mesh_outside(both, np.array([[0, 1, 2], [3, 4, 5]]))


def pictures(env, steps: int) -> list[dict[str, np.ndarray]]:
    """Both cameras' pictures after each of ``steps`` fixed, sweeping actions."""
    out = []
    for step in range(steps):
        action = np.random.default_rng(step).uniform(-0.6, 0.6, env.action_space.shape).astype(np.float32)
        env.step(action)
        sensors = env.unwrapped._get_obs_sensor_data()
        out.append({name: data["rgb"].numpy().copy() for name, data in sensors.items()})
    return out


@pytest.mark.skipif(importlib.util.find_spec("mikasa_robo_suite") is None, reason=MIKASA_MISSING)
def test_culled_pictures_are_the_same_bit_for_bit():
    """RememberColor3's harness env, its scene built anew at each reset: the pictures with every body drawn and with
    each camera's culled are equal, the wrist camera never draws its own mount, and a light that casts shadows turns
    culling off."""
    from sb3_memret.benchmark import harness

    env = harness.make_env("RememberColor3-VLA-v0", fresh_scenes=True)
    base = env.unwrapped
    full, cull = base.capture_sensor_data, FrustumCull(base)
    try:
        for seed in (5000, 5001):
            drawn = {}
            for culled in (False, True):
                base.capture_sensor_data = cull.capture if culled else full
                env.reset(seed=seed)
                drawn[culled] = pictures(env, 6)
            for before, after in zip(drawn[False], drawn[True]):
                assert before.keys() == after.keys() == {"base_camera", "hand_camera"}
                for name in before:
                    assert np.array_equal(before[name], after[name]), (seed, name)
            assert [body.entity.name for body in cull._blind["hand_camera"]] == ["camera_link"]
            assert cull._blind["base_camera"] == []
            hand = base._sensors["hand_camera"].camera._render_cameras[0]
            bodies = list(base.scene.sub_scenes[0].render_system.render_bodies)
            hidden = {body.entity.name for body in cull.hidden(hand, bodies, cull._blind["hand_camera"])}
            assert {"camera_link", "panda_link0"} <= hidden  # its mount, and the arm's base behind it
            assert all(body.visibility == 1.0 for body in bodies if body.entity.name == "camera_link")  # restored
        assert cullable(base)
        light = base.scene.sub_scenes[0].render_system.lights[0]
        light.shadow = True
        assert not cullable(base)
    finally:
        env.close()

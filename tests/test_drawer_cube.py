"""DrawerCubeTakeOut-v1 on the real SAPIEN simulator (CPU, no renderer)."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from mani_skill.utils.structs.pose import Pose

import sb3_memret.tasks.drawer.drawer_cube  # noqa: F401  (registers DrawerCubeTakeOut-v1)
from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.tasks.drawer.state import layer_containing
from sb3_memret.tasks.drawer.objects import OBJECT_SETS
from sb3_memret.tasks.rewards import PHI_MAX
from conftest import make_task_env


def place_cube(env, xyz):
    base = env.unwrapped
    base.objects[0].set_pose(Pose.create_from_pq(torch.tensor([xyz], dtype=torch.float32)))
    return base.evaluate()


def test_make_with_state_obs_and_no_renderer():
    env = gym.make("DrawerCubeTakeOut-v1", obs_mode="state", render_backend="none")
    obs, info = env.reset(seed=0)
    assert obs.shape == (1, 8 + 3 + 8)
    assert env.action_space.shape == (7,)
    assert env.unwrapped.control_mode == "pd_ee_delta_pose"
    assert not info["success"].item()
    env.close()


def test_observation_layout(task_env):
    obs, _ = task_env.reset(seed=1, options={"target_layer": 2})
    state = task_env.unwrapped.privileged_state()
    eef = obs["agent"]["eef_state"][0].numpy()
    np.testing.assert_allclose(eef[:3], state.eef_pos[0], atol=1e-5)
    np.testing.assert_allclose(eef[6:], [0.04, 0.04], atol=1e-3)  # gripper open at rest
    np.testing.assert_allclose(obs["extra"]["drawer_opening"][0].numpy(), 0.0, atol=1e-6)
    assert torch.all(obs["extra"]["target_detection"] == 0)  # hidden while its drawer is closed


def test_seeded_reset_is_reproducible(task_env):
    poses = []
    for seed in (7, 7, 8):
        task_env.reset(seed=seed)
        state = task_env.unwrapped.privileged_state()
        poses.append((state.target_layer[0], state.target_pos[0].copy(), state.target_quat[0].copy()))
    assert poses[0][0] == poses[1][0]
    np.testing.assert_array_equal(poses[0][1], poses[1][1])
    np.testing.assert_array_equal(poses[0][2], poses[1][2])
    assert not np.allclose(poses[0][1], poses[2][1])


def test_layer_is_uniformly_randomised_over_seeds(task_env):
    layers = []
    for seed in range(30):
        task_env.reset(seed=seed)
        layers.append(int(task_env.unwrapped.privileged_state().target_layer[0]))
    assert set(layers) == set(LAYERS)


@pytest.mark.parametrize("layer", LAYERS)
def test_cube_starts_in_its_layer_and_that_is_not_success(task_env, layer):
    task_env.reset(seed=3, options={"target_layer": layer})
    for _ in range(5):
        _, reward, terminated, _, info = task_env.step(np.zeros(7))
    assert info["target_in_layer"].item() == layer
    assert info["target_layer"].item() == layer
    assert not info["success"].item() and not terminated.item()
    # the default reward mode, normalized_dense, is the staged potential over its maximum
    assert reward.item() == pytest.approx(info["potential"].item() / PHI_MAX)


def test_success_geometry(task_env):
    task_env.reset(seed=0, options={"target_layer": 1})
    lay = task_env.unwrapped.layout
    # lifted clear above the cabinet
    info = place_cube(task_env, [lay.front_x + 0.1, 0.0, lay.top_z + 0.1])
    assert info["success"].item() and info["target_clear"].item()
    assert info["potential"].item() == pytest.approx(PHI_MAX)
    # pulled past the front, outside every drawer
    info = place_cube(task_env, [lay.front_x - 0.2, 0.0, 0.3])
    assert info["success"].item()
    # in the air in front of the cabinet but not past the margin, and below the top: not yet
    info = place_cube(task_env, [lay.front_x - 0.01, 0.0, 0.3])
    assert not info["success"].item()


def test_cube_inside_an_open_drawer_is_not_success(task_env):
    task_env.reset(seed=0, options={"target_layer": 2})
    base = task_env.unwrapped
    opening = torch.tensor([[0.0, 0.28, 0.0]])
    base.cabinet.set_qpos(opening)
    low, high = base.layout.inner_box(2, 0.28)
    info = place_cube(task_env, ((low + high) / 2).tolist())
    assert info["target_in_layer"].item() == 2
    assert not info["success"].item()
    obs = base.get_obs(info)
    assert obs["extra"]["target_detection"][0, 0] == 1.0  # its drawer is open: a camera sees it
    np.testing.assert_allclose(obs["extra"]["target_detection"][0, 1:4].numpy(), (low + high) / 2, atol=1e-5)


def test_cube_stays_hidden_when_another_drawer_opens(task_env):
    task_env.reset(seed=0, options={"target_layer": 3})
    base = task_env.unwrapped
    base.cabinet.set_qpos(torch.tensor([[0.28, 0.28, 0.0]]))
    obs = base.get_obs(base.evaluate())
    assert torch.all(obs["extra"]["target_detection"] == 0)


def test_unknown_cube_layer_option_is_refused(task_env):
    with pytest.raises(ValueError, match=r"drawer layer must be one of \[1, 2, 3\]"):
        task_env.reset(seed=0, options={"target_layer": 4})


def test_several_objects_one_per_drawer_and_the_rest_parked(objects_env):
    base = objects_env.unwrapped
    targets, layers = set(), set()
    for seed in range(12):
        objects_env.reset(seed=seed)
        state = base.privileged_state()
        placed = state.placed()
        assert len(placed) == 3 and sorted(placed.values()) == list(LAYERS)
        np.testing.assert_array_equal(layer_containing(state.object_pos[0], np.repeat(state.layer_boxes, 4, axis=0)),
                                      state.object_layer[0])  # each placed object lies in its drawer, the rest in none
        parked = state.object_layer[0] == 0
        assert np.all(state.object_pos[0, parked, 0] < 0)  # behind the robot, out of the cabinet
        target = state.target_name()
        assert placed[target] == state.target_layer[0] == state.target_in_layer[0]
        np.testing.assert_allclose(state.target_pos[0], state.object_pos[0, state.target_index[0]])
        targets.add(target)
        layers.add(int(state.target_layer[0]))
    assert targets == set(OBJECT_SETS["train"]) and layers == set(LAYERS)


def test_target_and_its_layer_can_be_fixed(objects_env):
    objects_env.reset(seed=5, options={"target": "tin", "target_layer": 2})
    state = objects_env.unwrapped.privileged_state()
    assert state.target_name() == "tin" and state.placed()["tin"] == 2


def test_only_the_target_is_detected_once_its_drawer_opens(objects_env):
    objects_env.reset(seed=3, options={"target": "brick", "target_layer": 3})
    base = objects_env.unwrapped
    base.cabinet.set_qpos(torch.tensor([[0.28, 0.28, 0.0]]))  # the two other objects' drawers
    obs = base.get_obs(base.evaluate())
    assert torch.all(obs["extra"]["target_detection"] == 0)
    base.cabinet.set_qpos(torch.tensor([[0.0, 0.0, 0.28]]))
    info = base.evaluate()
    obs = base.get_obs(info)
    state = base.privileged_state()
    assert obs["extra"]["target_detection"][0, 0] == 1.0
    np.testing.assert_allclose(obs["extra"]["target_detection"][0, 1:4].numpy(), state.target_pos[0], atol=1e-5)


def test_bad_object_settings_are_refused(objects_env):
    with pytest.raises(ValueError, match="objects must be distinct names from"):
        make_task_env(objects=("cube", "teapot"))
    with pytest.raises(ValueError, match=r"n_objects must be in \[1, 3\]"):
        make_task_env(objects=OBJECT_SETS["train"], n_objects=4)
    with pytest.raises(ValueError, match="target 'soap' is not one of this task's objects"):
        objects_env.reset(seed=0, options={"target": "soap"})

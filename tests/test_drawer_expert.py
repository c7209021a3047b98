"""The scripted frozen controller on the real simulator."""

import gymnasium as gym
import numpy as np
import pytest
import torch

from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.controller_specs import make_controller
from sb3_memret.tasks.drawer.expert import PLANT_GAIN, POS_SCALE, ROT_SCALE, Perception, Phase
from sb3_memret.tasks.drawer.cabinet import LAYERS
from sb3_memret.tasks.drawer.prompts import condition_prompt
from conftest import drawer_episode, make_task_env


@pytest.fixture(scope="module")
def controller():
    return ScriptedDrawerController()


@pytest.mark.parametrize("layer", LAYERS)
def test_oracle_prompt_takes_cube_out_of_each_layer(task_env, controller, layer):
    result = drawer_episode(task_env, controller, condition_prompt("oracle", layer), seed=11, layer=layer)
    assert result.success
    assert result.steps < 300


@pytest.mark.parametrize("layer", [2, 3])
def test_wrong_layer_prompt_fails(task_env, controller, layer):
    result = drawer_episode(task_env, controller, condition_prompt("wrong", layer), seed=12, layer=layer)
    assert not result.success
    assert controller.phases() == [Phase.IDLE]  # opened the named drawer, saw no cube, stopped


def test_no_memory_prompt_opens_top_drawer(task_env, controller):
    assert drawer_episode(task_env, controller, condition_prompt("none", 1), seed=13, layer=1).success
    assert not drawer_episode(task_env, controller, condition_prompt("none", 2), seed=13, layer=2).success
    assert task_env.unwrapped.privileged_state().drawer_qpos[0, 0] > 0.2  # it opened layer 1


def test_prompt_changed_mid_episode_changes_behaviour(controller):
    env = make_task_env(max_episode_steps=700)
    obs, _ = env.reset(seed=5, options={"target_layer": 2})
    controller.reset([5])
    info = {}
    for step in range(0, 700, 8):
        prompt = condition_prompt("oracle", 1 if step < 200 else 2)  # wrong memory, then the true one
        for action in controller.act(obs, [prompt])[0][:8]:
            obs, _, terminated, truncated, info = env.step(action)
        if step == 192:
            assert obs["extra"]["drawer_opening"][0, 0] > 0.2  # it had opened the top drawer
        if terminated or truncated:
            break
    assert info["success"].item()
    opening = obs["extra"]["drawer_opening"][0].numpy()
    assert opening[0] < 0.03 and opening[1] > 0.2  # closed the wrong drawer, opened the right one
    env.close()


def test_controller_cannot_see_the_cube_layer():
    """Same observation, different hidden layer: identical actions until a drawer shows the cube."""
    chunks = []
    for layer in (2, 3):
        env = make_task_env(robot_init_qpos_noise=0.0)
        obs, _ = env.reset(seed=21, options={"target_layer": layer})
        ctrl = ScriptedDrawerController()
        ctrl.reset([21])
        chunks.append(ctrl.act(obs, ["pick out the cube."]))
        env.close()
    np.testing.assert_array_equal(chunks[0], chunks[1])


def test_chunks_are_batched_and_bounded(task_env, controller):
    obs, _ = task_env.reset(seed=0, options={"target_layer": 1})
    batch = {k: {kk: vv.repeat(3, *[1] * (vv.ndim - 1)) for kk, vv in v.items()} for k, v in obs.items()}
    controller.reset([0, 1, 2])
    prompts = [condition_prompt("oracle", layer) for layer in LAYERS]
    chunks = controller.act(batch, prompts)
    assert chunks.shape == (3, controller.spec.chunk_len, 7)
    assert np.all(np.abs(chunks) <= 1.0 + 1e-6)
    assert not np.allclose(chunks[0], chunks[2])  # different layers, different motion


def test_malformed_prompt_is_refused(task_env, controller):
    obs, _ = task_env.reset(seed=0)
    controller.reset([0])
    with pytest.raises(ValueError, match="matches no trained template"):
        controller.act(obs, ["pick out the cube. the cube is in the second drawer."])
    with pytest.raises(ValueError, match="malformed prompt"):
        controller.act(obs, ["Pick out the cube"])


def test_batch_size_must_match_reset(task_env, controller):
    obs, _ = task_env.reset(seed=0)
    controller.reset([0, 1])
    with pytest.raises(RuntimeError, match="reset\\(\\) was called for 2 envs"):
        controller.act(obs, ["pick out the cube."])


def test_mismatched_action_convention_is_refused(controller):
    env = gym.make("DrawerCubeTakeOut-v1", obs_mode="state_dict", render_backend="none", control_mode="pd_joint_delta_pos")
    with pytest.raises(ValueError, match="'pd_ee_delta_pose' actions but the env's control mode is 'pd_joint_delta_pos'"):
        controller.check_env(env)
    env.close()


def test_unknown_controller_spec_is_refused():
    with pytest.raises(ValueError, match="unknown controller 'pi0'"):
        make_controller("pi0", "drawer")


def test_action_convention_matches_the_simulator(task_env):
    """The controller's model of pd_ee_delta_pose: base-frame deltas, rotation sign, tracking gain."""
    obs, _ = task_env.reset(seed=0, options={"target_layer": 1})
    before = Perception.from_obs(obs, 0)
    turn, move = 0.02, 0.005  # per step: +z rotation (rad) and +x translation (m)
    action = np.zeros(7, dtype=np.float32)
    action[0] = move / (PLANT_GAIN * POS_SCALE)
    action[5] = turn / (PLANT_GAIN * ROT_SCALE)
    action[6] = 1.0
    for _ in range(10):
        obs, *_ = task_env.step(action)
    after = Perception.from_obs(obs, 0)
    yaw = (after.tcp_rot * before.tcp_rot.inv()).as_rotvec()
    assert yaw[2] == pytest.approx(10 * turn, rel=0.25)
    assert np.abs(yaw[:2]).max() < 0.03
    assert after.tcp_pos[0] - before.tcp_pos[0] == pytest.approx(10 * move, rel=0.25)


@pytest.mark.parametrize("phase", [Phase.DESCEND])
def test_a_drawer_pushed_half_shut_under_the_hand_is_opened_again(controller, phase):
    """A state the expert's own episodes never reach but a learned controller's do (DAgger labels it): the named
    drawer slides half shut while the hand goes for the cube. The expert goes back to the handle, opens it again
    and takes the cube out, instead of reaching into the shut drawer."""
    env = make_task_env(max_episode_steps=800)
    obs, _ = env.reset(seed=21, options={"target_layer": 3})
    controller.reset([21])
    prompt, info, pushed = condition_prompt("oracle", 3), {}, False
    for _ in range(0, 800, 8):
        chunk = controller.act(obs, [prompt])[0][:8]
        if not pushed and controller.phases() == [phase]:
            cabinet = env.unwrapped.cabinet
            qpos = cabinet.get_qpos().clone()
            qpos[0, 2] = 0.08  # layer 3 from fully open (0.27 m) to 8 cm
            cabinet.set_qpos(qpos)
            pushed = True
            obs, *_ = env.step(np.array([0, 0, 0, 0, 0, 0, 1], dtype=np.float32))  # hold still: a fresh look
            chunk = controller.act(obs, [prompt])[0][:8]  # the expert decides again, as DAgger asks it to
        for action in chunk:
            obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    env.close()
    assert pushed and info["success"].item()


def _seen(obs, tcp=None, fingers=None, opening=None, target=None):
    """``obs`` with the hand, the drawer openings and the detected target replaced (a state another policy led to)."""
    obs = {group: {key: value.clone() for key, value in part.items()} for group, part in obs.items()}
    if tcp is not None:
        obs["agent"]["eef_state"][0, :3] = torch.tensor(tcp)
    if fingers is not None:
        obs["agent"]["eef_state"][0, 6:8] = fingers / 2
    if opening is not None:
        obs["extra"]["drawer_opening"][0] = torch.tensor(opening)
    if target is not None:
        obs["extra"]["target_detection"][0] = torch.tensor([1.0, *target, 1.0, 0.0, 0.0, 0.0])
    return obs


def _enter(controller, phase, obs, prompt):
    """Lead the expert into ``phase`` as its own episode would have (the plan is the expert's memory)."""
    controller.reset([0])
    controller.act(obs, [prompt])
    controller._plans[0].phase, controller._plans[0].calls = phase, 0


@pytest.mark.parametrize("phase", [Phase.RISE, Phase.ABOVE_CUBE, Phase.DESCEND])
def test_a_cube_already_in_hand_is_lifted(task_env, controller, phase):
    """DAgger's learner may grasp the cube while the expert still steers to it; the expert's label is then to lift
    with the gripper closed, not to open and go above the cube again."""
    obs, _ = task_env.reset(seed=0, options={"target_layer": 3})
    prompt = condition_prompt("oracle", 3)
    _enter(controller, phase, obs, prompt)
    held = _seen(obs, tcp=[0.6, 0.0, 0.13], fingers=0.04, opening=[0.0, 0.0, 0.27], target=[0.6, 0.005, 0.13])
    chunk = controller.act(held, [prompt])[0]
    assert controller.phases() == [Phase.LIFT]
    assert np.all(chunk[:, 6] == -1.0) and chunk[:, 2].sum() > 0  # keeps its grip, goes up


def test_a_dropped_cube_is_grasped_again(controller):
    """The cube slips out while lifting: the expert lets go, backs off and takes it out again."""
    env = make_task_env(max_episode_steps=800)
    obs, _ = env.reset(seed=11, options={"target_layer": 2})
    controller.reset([11])
    prompt, info, dropped, phases = condition_prompt("oracle", 2), {}, 0, []
    for _ in range(0, 800, 8):
        chunk = controller.act(obs, [prompt])[0][:8]
        phases.append(controller.phases()[0])
        if not dropped and phases[-1] is Phase.LIFT:
            chunk = chunk.copy()
            chunk[:, 6] = 1.0  # the fingers open: the cube falls back into the drawer
            dropped = len(phases)
        for action in chunk:
            obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    env.close()
    assert dropped and Phase.DESCEND in phases[dropped:]  # went for it again
    assert info["success"].item()


@pytest.mark.parametrize(("opening", "cube_x", "decision"), [
    (0.27, 0.60, Phase.RISE),  # open, the cube where it lies in a pulled drawer: reach in
    (0.18, 0.69, Phase.REACH_HANDLE),  # half shut: the cube sits under the handle above, so open it again
    (0.27, 0.72, Phase.IDLE),  # open as far as it goes and the cube pushed deep: stop rather than jam the hand
])
def test_the_expert_reaches_in_only_where_the_hand_fits(task_env, controller, opening, cube_x, decision):
    obs, _ = task_env.reset(seed=0, options={"target_layer": 3})
    prompt = condition_prompt("oracle", 3)
    _enter(controller, Phase.BACK_OFF, obs, prompt)
    seen = _seen(obs, tcp=[0.3, 0.0, 0.2], fingers=0.08, opening=[0.0, 0.0, opening], target=[cube_x, 0.0, 0.13])
    controller.act(seen, [prompt])
    assert controller.phases() == [decision]


def test_a_hand_another_policy_brought_to_the_handle_goes_on_from_there(task_env, controller):
    """The learner need not pass the expert's own pre-grasp point: a hand already on the insertion line is labelled
    to go in, and fingers already closed on the handle to pull, instead of back to where the expert would start."""
    from sb3_memret.tasks.drawer.expert import HANDLE_APPROACH, R_HANDLE

    obs, _ = task_env.reset(seed=0, options={"target_layer": 2})
    prompt = condition_prompt("oracle", 2)
    handle = controller.layout.handle_center(2, 0.0)
    turned = R_HANDLE.as_rotvec()
    for tcp, fingers, phase in ((handle - 0.04 * HANDLE_APPROACH, 0.08, Phase.INSERT),
                                (handle, 0.02, Phase.PULL),
                                (handle + [0, 0, 0.035], 0.02, Phase.PULL),  # anywhere along the bar
                                (handle - 0.04 * HANDLE_APPROACH + [0, 0.05, 0], 0.08, Phase.REACH_HANDLE)):
        _enter(controller, Phase.REACH_HANDLE, obs, prompt)
        seen = _seen(obs, tcp=list(tcp), fingers=fingers, opening=[0.0, 0.0, 0.0])
        seen["agent"]["eef_state"][0, 3:6] = torch.tensor(turned)
        controller.act(seen, [prompt])
        assert controller.phases() == [phase], (tcp, fingers)

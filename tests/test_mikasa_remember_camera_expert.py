"""RememberColor's touch expert on the harness's inputs alone (``scripted-camera``), and the registry of camera
experts: the cubes it places from the base camera, when it heads for the named one, and an episode through MIKASA's
harness as a protocol entry."""

import numpy as np
import pytest

from mikasa_support import MIKASA_MISSING, camera_expert_cells

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controller_specs import make_controller  # noqa: E402
from sb3_memret.controllers.base import as_numpy  # noqa: E402
from sb3_memret.controllers.pacing import replan_interval  # noqa: E402
from sb3_memret.tasks import make_task  # noqa: E402
from sb3_memret.tasks.mikasa.camera_experts import (  # noqa: E402
    camera_expert, has_camera_expert, register_camera_expert)
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, base_camera_layout  # noqa: E402
from sb3_memret.tasks.mikasa.remember.camera_expert import CameraTouchController  # noqa: E402
from sb3_memret.tasks.mikasa.remember.color import RememberColorTask  # noqa: E402
from sb3_memret.tasks.mikasa.core.touch_expert import colour_prompt  # noqa: E402

ROW = {"red": np.array([0.0, -0.2]), "lime": np.array([0.0, 0.0]), "blue": np.array([0.0, 0.2])}


def _obs(tcp, seen):
    """The hand's pose as the harness gives it, and for the base camera's "image" the layout it shows (read with
    ``read_layout=lambda seen: seen``)."""
    return {"extra": {"tcp_pose": np.array([[*tcp, 0, 1, 0, 0]])}, "sensor_data": {"base_camera": {"rgb": [seen]}}}


def _controller(wait_for_all=False):
    task = make_task("RememberColor3-VLA-v0")
    return CameraTouchController(task.words, task.template, paced_every=4, default=task.words[0],
                                 wait_for_all=wait_for_all, read_layout=lambda seen: seen)


def test_it_waits_while_only_the_cue_shows_then_heads_for_the_cube_its_prompt_names():
    controller = _controller()
    assert controller.spec.harness_inputs and controller.spec.needs_images and controller.stateful
    controller.reset([0])
    ready = np.asarray(controller.gains.ready)
    chunk = controller.act(_obs(ready, {"blue": np.zeros(2)}), [colour_prompt("blue")])[0]  # the cue, alone
    assert np.abs(chunk[:, :3]).max() < 1e-6 and controller.layouts[0].places == {}  # never placed where a cue was
    assert controller.reads_images()
    chunk = controller.act(_obs(ready, ROW), [colour_prompt("blue")])[0]
    assert chunk[0, 1] > 0.5  # towards blue, at y = +0.2
    assert not controller.reads_images()  # every cube placed: the benchmark need not render for it
    chunk = controller.act(_obs(ready, {}), [colour_prompt(None)])[0]  # no fact: its guess, the first colour
    assert chunk[0, 1] < -0.5 and np.allclose(controller.layouts[0].places["red"], ROW["red"])
    controller.reset_envs([0], [1])
    assert controller.layouts[0].places == {} and controller.hand.sent[0] is None and controller.reads_images()


def test_where_no_wrapper_freezes_the_arm_it_waits_until_every_cube_is_placed():
    controller = _controller(wait_for_all=True)
    controller.reset([0])
    ready = np.asarray(controller.gains.ready)
    partly = {c: p for c, p in ROW.items() if c != "lime"}  # the arm hides lime
    chunk = controller.act(_obs(ready, partly), [colour_prompt("blue")])[0]
    assert np.abs(chunk[:, :3]).max() < 1e-6  # blue is placed, but the choice waits for every cube
    chunk = controller.act(_obs(ready, ROW), [colour_prompt("blue")])[0]
    assert chunk[0, 1] > 0.5


def test_the_registry_builds_each_family_s_camera_expert_and_takes_one_of_your_own():
    long = make_controller("scripted-camera", "RememberColor9-Long-VLA-v0")
    assert isinstance(long, CameraTouchController) and long.wait_for_all and len(long.vocabulary) == 9
    assert not make_controller("scripted-camera", "RememberColor3-VLA-v0").wait_for_all  # its arm is frozen
    assert replan_interval(make_task("RememberColor3-VLA-v0"), None, long) == 4

    class MyColours(RememberColorTask):  # a task of one's own inherits its family's
        pass

    mine = MyColours("RememberColor5-VLA-v0")
    assert has_camera_expert(mine) and len(camera_expert(mine).vocabulary) == 5
    built = []
    register_camera_expert(MyColours, lambda task: built.append(task) or _controller())
    try:
        camera_expert(mine)
        assert built == [mine]
    finally:
        from sb3_memret.tasks.mikasa import camera_experts

        camera_experts._REGISTERED.pop(MyColours)
    with pytest.raises(TypeError, match="Task subclass"):
        register_camera_expert(dict, lambda task: None)
    assert not has_camera_expert(make_task("drawer"))


@pytest.mark.parametrize("seed", [5000, 5006])  # cubes touching in the image: cyan, lime, blue; cyan and olive
def test_the_nine_cubes_are_placed_from_the_base_camera_within_a_centimetre(seed):
    task = make_task("RememberColor9-VLA-v0")
    env = task.make_env(obs_mode="rgb")
    try:
        obs, _ = env.reset(seed=seed)
        places = {}
        for _ in range(12):  # the cue (1-5 steps) and the delay (1-5): the cubes are out by then
            obs, *_ = env.step(np.zeros(env.action_space.shape))
            places = base_camera_layout(obs["sensor_data"]["base_camera"]["rgb"], 9)
            if len(places) == 9:
                break
        truth = {task.words[i]: as_numpy(cube.pose.p).reshape(-1) for i, cube in env.unwrapped.cubes.items()}
        assert sorted(places) == sorted(task.words)
        errors = {c: float(np.linalg.norm(p - truth[c][:2])) for c, p in places.items()}
        assert max(errors.values()) < 0.01, errors
        assert all(abs(truth[c][2] - LAYOUT_PLANE_Z) < 1e-3 for c in truth)  # cast onto their centres' plane
    finally:
        env.close()


@pytest.mark.slow
def test_through_the_harness_it_touches_the_cue_s_cube_as_a_protocol_entry(tmp_path):
    """RememberColor3 at a development seed: the oracle's fact and the writer's (written) each take it to success,
    reading only the harness's observation (the guard refuses any other read while the agent acts)."""
    results, cells = camera_expert_cells("RememberColor3-VLA-v0", tmp_path)
    assert results["privileged_upper_bound"] is False
    assert cells["oracle"]["successes"] == cells["written"]["successes"] == [True], cells

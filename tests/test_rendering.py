"""Camera images from the real renderer on the CPU (the project's lavapipe), rendered only at decisions."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sb3_memret.common.rendering import RENDERER_DIR_ENV, RendererNotFoundError, use_cpu_renderer
from sb3_memret.physics.chunks import execute_chunk

CAMERAS = ("base_camera", "hand_camera")


def images(obs: dict) -> dict[str, np.ndarray]:
    return {cam: obs["sensor_data"][cam]["rgb"][0].cpu().numpy() for cam in CAMERAS}


def test_a_missing_renderer_names_the_command_that_installs_it(tmp_path, monkeypatch):
    monkeypatch.delenv("VK_ICD_FILENAMES", raising=False)
    monkeypatch.setenv(RENDERER_DIR_ENV, str(tmp_path / "none"))
    with pytest.raises(RendererNotFoundError, match=r"lvp_icd\.json does not exist; install it with: make renderer"):
        use_cpu_renderer()
    monkeypatch.setenv("VK_ICD_FILENAMES", str(tmp_path / "gone.json"))
    with pytest.raises(RendererNotFoundError, match=r"VK_ICD_FILENAMES names .*gone\.json.*which do not exist"):
        use_cpu_renderer()


def test_both_cameras_render_real_images(rgb_task_env):
    obs, _ = rgb_task_env.reset(seed=0, options={"target_layer": 1})
    for cam, image in images(obs).items():
        assert image.shape == (224, 224, 3) and image.dtype == np.uint8, cam
        assert image.std() > 10 and len(np.unique(image.reshape(-1, 3), axis=0)) > 10, f"{cam} looks blank"
    assert not np.array_equal(*images(obs).values())


def test_opening_a_drawer_changes_what_the_base_camera_sees(rgb_task_env):
    obs, _ = rgb_task_env.reset(seed=0, options={"target_layer": 1})
    closed = images(obs)["base_camera"].astype(np.int16)
    task = rgb_task_env.unwrapped
    task.cabinet.set_qpos(torch.tensor([[0.25, 0.0, 0.0]]))
    opened = images(task.get_obs())["base_camera"].astype(np.int16)
    changed = np.abs(opened - closed).max(axis=-1) > 30
    assert changed.mean() > 0.01, f"only {changed.mean():.2%} of the pixels changed"
    rgb_task_env.reset(seed=0)
    again = images(task.get_obs())["base_camera"].astype(np.int16)
    assert np.abs(again - closed).max(axis=-1).__gt__(30).mean() < 0.005  # closed again: the same picture


def test_sensors_paused_leaves_out_images(rgb_task_env):
    rgb_task_env.reset(seed=0)
    with rgb_task_env.unwrapped.sensors_paused():
        obs, *_ = rgb_task_env.step(np.zeros(7, np.float32))
    assert "sensor_data" not in obs and obs["agent"]["eef_state"].shape == (1, 8)
    obs, *_ = rgb_task_env.step(np.zeros(7, np.float32))
    assert set(obs["sensor_data"]) == set(CAMERAS)


def test_a_chunk_renders_once_for_the_next_decision(rgb_task_env, monkeypatch):
    task = rgb_task_env.unwrapped
    rgb_task_env.reset(seed=0)
    captures = []
    original = task.capture_sensor_data
    monkeypatch.setattr(task, "capture_sensor_data", lambda: captures.append(1) or original())
    outcome = execute_chunk(rgb_task_env, np.zeros((8, 7), np.float32))
    assert outcome.steps == 8 and len(captures) == 1
    assert images(outcome.obs)["base_camera"].shape == (224, 224, 3)


def test_a_drawer_env_made_through_gymnasium_sets_up_the_cpu_renderer_itself():
    """The README's gymnasium path with cameras works in a fresh process that never called use_cpu_renderer."""
    import os
    import subprocess
    import sys

    code = ("import gymnasium as gym, sb3_memret.tasks.drawer.drawer_cube\n"
            "env = gym.make('DrawerCubeTakeOut-v1', obs_mode='rgb', render_backend='cpu')\n"
            "obs, _ = env.reset(seed=0)\n"
            "print(tuple(obs['sensor_data']['base_camera']['rgb'].shape))\n")
    env = {k: v for k, v in os.environ.items() if k != "VK_ICD_FILENAMES"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "(1, 224, 224, 3)"

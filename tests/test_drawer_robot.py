"""The drawer's light Panda: decimated visual meshes, made once into the cache, the same physics, nearly the same
pictures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from conftest import make_task_env
from sb3_memret.tasks.drawer import robot
from sb3_memret.tasks.drawer.drawer_cube import DEFAULT_ROBOT
from sb3_memret.tasks.drawer.robot import LIGHT_PANDA_UID, decimate_glb, light_panda_dir, light_panda_urdf


def test_decimation_cuts_big_meshes_to_the_fraction_and_keeps_small_ones_and_colours(tmp_path):
    scene = trimesh.Scene()
    big = trimesh.creation.icosphere(subdivisions=5)  # 20480 faces
    big.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        baseColorFactor=[200, 10, 10, 255]))
    scene.add_geometry(big, geom_name="big")
    scene.add_geometry(trimesh.creation.box(), geom_name="small")  # 12 faces
    scene.export(tmp_path / "in.glb")
    before, after = decimate_glb(tmp_path / "in.glb", tmp_path / "out.glb", keep=0.1, min_faces=2000)
    assert before == 20480 + 12
    light = trimesh.load(tmp_path / "out.glb", force="scene")
    faces = {name: len(mesh.faces) for name, mesh in light.geometry.items()}
    assert faces["small"] == 12 and 1500 <= faces["big"] <= 2600 and after == sum(faces.values())
    assert list(light.geometry["big"].visual.material.baseColorFactor[:3]) == [200, 10, 10]
    radius = np.linalg.norm(light.geometry["big"].vertices, axis=1)
    assert np.abs(radius - 1.0).max() < 0.05  # still the sphere
    with pytest.raises(ValueError, match=r"keep must be in \(0, 1\], got 0"):
        decimate_glb(tmp_path / "in.glb", tmp_path / "bad.glb", keep=0)


def test_the_urdf_is_made_once_with_every_file_it_names(tmp_path, monkeypatch):
    monkeypatch.setenv(robot.CACHE_ENV, str(tmp_path))
    urdf = light_panda_urdf()
    assert urdf.parent == light_panda_dir() and urdf.parent.parent == tmp_path
    assert urdf.with_suffix(".srdf").is_file()
    named = [line.split('filename="')[1].split('"')[0] for line in urdf.read_text().splitlines() if 'filename="' in line]
    visual = [path for path in named if path.endswith(".glb")]
    assert len(visual) >= 10 and all(path.startswith(str(urdf.parent)) for path in visual)
    assert all(trimesh.load(path, force="scene").geometry for path in visual)
    assert all(path.startswith(str(robot.SOURCE_URDF.parent)) for path in named if not path.endswith(".glb"))
    assert all(Path(path).is_file() for path in named)
    stamp = urdf.stat().st_mtime_ns
    assert light_panda_urdf() == urdf and urdf.stat().st_mtime_ns == stamp  # kept, not made again
    assert not [p for p in tmp_path.iterdir() if p != urdf.parent]  # no staging folder left behind


def test_an_unwritable_cache_is_named_with_the_way_out(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv(robot.CACHE_ENV, str(blocker / "cache"))  # a folder inside a file cannot be made
    with pytest.raises(OSError, match=r"cannot write the light Panda's meshes into '.*a-file/cache' .*SB3_MEMRET_CACHE "
                                      r".*robot_uids='panda'"):
        light_panda_urdf()


def test_the_light_panda_moves_exactly_as_maniskills(tmp_path):
    actions = np.random.default_rng(0).uniform(-1, 1, (40, 7)).astype(np.float32)
    qpos = {}
    for uid in ("panda", LIGHT_PANDA_UID):
        env = make_task_env(obs_mode="state_dict", render_backend="none", robot_uids=uid)
        env.reset(seed=5)
        for action in actions:
            env.step(action)
        qpos[uid] = env.unwrapped.agent.robot.get_qpos().numpy()
        env.close()
    np.testing.assert_array_equal(qpos["panda"], qpos[LIGHT_PANDA_UID])


def test_the_light_panda_looks_like_maniskills(rgb_task_env):
    assert rgb_task_env.unwrapped.agent.uid == DEFAULT_ROBOT
    pictures = []
    for uid in ("panda", LIGHT_PANDA_UID):
        env = make_task_env(obs_mode="rgb", render_backend="cpu", robot_init_qpos_noise=0.0, robot_uids=uid)
        try:
            obs, _ = env.reset(seed=0, options={"target_layer": 2})
            pictures.append({cam: obs["sensor_data"][cam]["rgb"][0].numpy().astype(np.int16)
                             for cam in ("base_camera", "hand_camera")})
        finally:
            env.close()
    for cam in pictures[0]:
        difference = np.abs(pictures[0][cam] - pictures[1][cam])
        assert difference.mean() < 3.0, f"{cam}: mean difference {difference.mean():.2f} of 255"
        assert (difference.max(axis=-1) > 8).mean() < 0.05, cam


def test_an_env_says_which_robot_it_renders_and_state_controllers_serve_any():
    from sb3_memret.controller_specs import make_controller
    from sb3_memret.physics.backends import TaskEnvInfo

    env = make_task_env(obs_mode="state_dict", render_backend="none", robot_uids="panda")
    try:
        assert TaskEnvInfo.of(env).robot == "panda"
        make_controller("learned-state", "drawer").check_env(env)  # reads no camera: any robot's look will do
    finally:
        env.close()

"""Expert demonstrations: the planned prompt mix, what a frame holds (and does not reveal), lerobot's reader
on what was written, DAgger labels, and an interrupted recording keeping its saved episodes."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_memret.controllers.observation import IMAGE_KEYS, STATE_NAMES
from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.controllers.prompts import INSTRUCTION, parse_prompt
from sb3_memret.tasks.drawer.prompts import condition_prompt
from sb3_memret.stage1.demos import DemoEpisode, PromptMix, plan_episodes, read_episode_log, record_demos, record_episode

DETECTION = slice(STATE_NAMES.index("target_visible"), STATE_NAMES.index("target_qz") + 1)


def read_dataset(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(f"local/{root.name}", root=root, video_backend="pyav")


def test_planned_prompts_are_bare_or_single_cube_facts():
    episodes = plan_episodes(300, seed=7, noise=0.05, noisy_fraction=0.5)
    assert [e.seed for e in episodes] == list(range(7, 307))
    assert [e.target_layer for e in episodes[:6]] == [1, 2, 3, 1, 2, 3]
    kinds = {"bare": 0, "matching": 0, "mismatched": 0}
    for e in episodes:
        parsed = parse_prompt(e.prompt)
        assert len(parsed.facts) <= 1 and all("cube" in dict(f.fields).values() for f in parsed.facts)
        kinds["bare" if parsed.layer is None else "matching" if parsed.layer == e.target_layer else "mismatched"] += 1
    assert kinds["bare"] == pytest.approx(60, abs=20) and kinds["mismatched"] == pytest.approx(60, abs=20)
    assert {e.noise for e in episodes} == {0.0, 0.05}
    assert sum(e.noise > 0 for e in episodes) == pytest.approx(150, abs=30)
    with pytest.raises(ValueError, match="must be non-negative and sum to 1"):
        PromptMix(0.5, 0.5, 0.5)


def test_a_frame_never_reveals_the_closed_drawers_cube(task_env):
    expert = ScriptedDrawerController()
    frames = record_episode(task_env, expert, DemoEpisode(3, 2, condition_prompt("oracle", 2)))
    assert frames.success and len(frames.states) == len(frames.actions) < 400
    visible = frames.states[:, DETECTION][:, 0] > 0.5
    assert not visible[0] and visible[-1]
    assert np.all(frames.states[~visible, DETECTION] == 0.0)  # zeros until the drawer is open: no layer leak
    assert np.abs(frames.actions).max() <= 1.0 + 1e-6


def test_empty_named_drawer_ends_the_episode_once_the_expert_idles(task_env):
    frames = record_episode(task_env, ScriptedDrawerController(), DemoEpisode(4, 3, INSTRUCTION), idle_stop=16)
    assert not frames.success and len(frames.actions) < 400
    assert np.all(frames.actions[-16:, :6] == pytest.approx(0.0, abs=0.05))  # holding still


def test_dagger_frames_follow_the_learner_with_the_experts_labels(task_env):
    class Stubborn(ScriptedDrawerController):
        """A learner that always heads for the top drawer, whatever its prompt says."""

        def act(self, obs, prompts, check_prompts=True):
            return super().act(obs, [INSTRUCTION] * len(prompts))

    expert = ScriptedDrawerController()
    frames = record_episode(task_env, expert, DemoEpisode(5, 3, condition_prompt("oracle", 3)), learner=Stubborn())
    assert frames.learner_acted and not frames.success
    # the learner opened the top drawer, yet the labels keep asking for the bottom one
    opening_1 = frames.states[:, STATE_NAMES.index("opening_1")]
    assert opening_1.max() > 0.2
    labels_dz = frames.actions[:40, 2].sum()
    learner_obs_z = frames.states[:40, STATE_NAMES.index("tcp_z")]
    assert labels_dz < 0 and learner_obs_z[-1] > learner_obs_z[0] - 0.05


def test_recorded_dataset_reads_back_with_lerobot(tmp_path):
    episodes = [DemoEpisode(11, 1, condition_prompt("oracle", 1)), DemoEpisode(12, 2, INSTRUCTION, noise=0.05)]
    out = record_demos(tmp_path / "demos", episodes, max_steps=60)
    dataset = read_dataset(out)
    assert dataset.num_episodes == 2 and dataset.fps == 20
    assert set(dataset.meta.tasks.index) == {e.prompt for e in episodes}
    frame = dataset[0]
    assert frame["observation.state"].shape == (19,) and frame["action"].shape == (7,)
    assert frame["task"] == episodes[0].prompt
    log = read_episode_log(out)
    assert [r["seed"] for r in log] == [11, 12] and [r["frames"] for r in log] == [60, 60]
    with pytest.raises(FileExistsError, match="already exists"):
        record_demos(out, episodes)


def test_interrupted_recording_keeps_saved_episodes(tmp_path):
    episodes = [DemoEpisode(20 + k, 1, INSTRUCTION) for k in range(3)]

    def interrupt(frames):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        record_demos(tmp_path / "demos", episodes, max_steps=24, on_episode=interrupt)
    assert read_dataset(tmp_path / "demos").num_episodes == 1


def test_cameras_are_recorded_under_the_libero_keys(tmp_path):
    out = record_demos(tmp_path / "demos", [DemoEpisode(30, 2, condition_prompt("oracle", 2))], render_backend="cpu",
                       max_steps=9)
    frame = read_dataset(out)[8]
    for key in IMAGE_KEYS:
        assert frame[key].shape == (3, 224, 224) and float(frame[key].std()) > 0.01


def test_decision_frames_carry_the_labels_of_their_chunk(task_env):
    episode = DemoEpisode(3, 2, condition_prompt("oracle", 2))
    every = record_episode(task_env, ScriptedDrawerController(), episode)
    decisions = record_episode(task_env, ScriptedDrawerController(), episode, frames="decisions")
    assert len(decisions.actions) == len(every.actions)  # the same episode, labelled at every step
    np.testing.assert_allclose(decisions.actions, every.actions, atol=1e-3)  # (contacts differ in the last bits)
    assert list(decisions.frame_steps) == list(range(0, len(every.actions), 8))
    np.testing.assert_allclose(decisions.states, every.states[::8], atol=1e-2)
    chunks, pad = decisions.chunks(32)
    np.testing.assert_array_equal(chunks[1], decisions.actions[8:40])
    left = len(decisions.actions) - decisions.frame_steps[-1]
    assert not pad[-1, :left].any() and pad[-1, left:].all()
    with pytest.raises(ValueError, match="unknown frames 'some'"):
        record_episode(task_env, ScriptedDrawerController(), episode, frames="some")


def test_decision_frames_render_only_where_a_controller_acts(tmp_path):
    from sb3_memret.controllers.observation import ACTION_CHUNK_KEY, CHUNK_PAD_KEY

    out = record_demos(tmp_path / "demos", [DemoEpisode(30, 2, condition_prompt("oracle", 2))], render_backend="cpu",
                       max_steps=17, frames="decisions", image_size=48)
    dataset = read_dataset(out)
    assert len(dataset) == 3 and read_episode_log(out)[0]["steps"] == 17  # steps 0, 8 and 16 of 17
    frame = dataset[2]
    assert frame[ACTION_CHUNK_KEY].shape == (32, 7) and int(frame[CHUNK_PAD_KEY].sum()) == 31
    for key in IMAGE_KEYS:
        assert frame[key].shape == (3, 48, 48) and float(frame[key].std()) > 0.01

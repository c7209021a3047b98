"""Expert demonstrations through the one recorder: the drawer's and the generic plan, what a frame holds (and does not
reveal), lerobot's reader on what was written, DAgger labels, and an interrupted recording keeping its saved episodes."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_memret.controllers.observation import IMAGE_KEYS, STATE_KEY, STATE_NAMES
from sb3_memret.controllers.prompts import parse_prompt
from sb3_memret.stage1.demos import DemoRecorder, read_episode_log, record_demos
from sb3_memret.tasks.demos import DemoEpisode, PromptMix, plan_episodes
from sb3_memret.tasks.drawer import DrawerTask
from sb3_memret.tasks.drawer.expert import ScriptedDrawerController
from sb3_memret.tasks.drawer.prompts import INSTRUCTION, TEMPLATE, location_text, named_layer

DETECTION = slice(STATE_NAMES.index("target_visible"), STATE_NAMES.index("target_qz") + 1)


def at(seed: int, layer: int, named: int | None = None, noise: float = 0.0) -> DemoEpisode:
    """A drawer episode with the cube in ``layer`` and a prompt naming layer ``named`` (None: the bare instruction)."""
    facts = () if named is None else (location_text("cube", named),)
    kind = "bare" if named is None else "matching" if named == layer else "mismatched"
    return DemoEpisode(seed, kind, noise, {"target_layer": layer, "target": "cube"}, facts)


def prompt_of(episode: DemoEpisode) -> str:
    return " ".join([INSTRUCTION, *episode.facts])


def states(recorded) -> np.ndarray:
    return np.stack([frame[STATE_KEY] for frame in recorded.frames])


@pytest.fixture(scope="module")
def recorder():
    recorder = DemoRecorder(DrawerTask(), "none")
    yield recorder
    recorder.env.close()


def read_dataset(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(f"local/{root.name}", root=root, video_backend="pyav")


def test_the_drawers_plan_cycles_its_layers_with_bare_or_single_cube_facts():
    episodes = DrawerTask().plan_demos(300, seed=7, noise=0.05, noisy_fraction=0.5)
    assert [e.seed for e in episodes] == list(range(7, 307))
    assert [e.reset_options["target_layer"] for e in episodes[:6]] == [1, 2, 3, 1, 2, 3]
    kinds = {"bare": 0, "matching": 0, "mismatched": 0}
    for e in episodes:
        parsed = parse_prompt(prompt_of(e), TEMPLATE)
        assert len(parsed.facts) <= 1 and all("cube" in dict(f.fields).values() for f in parsed.facts)
        layer = e.reset_options["target_layer"]
        named = named_layer(parsed)
        seen = "bare" if named is None else "matching" if named == layer else "mismatched"
        assert seen == e.prompt_kind
        kinds[seen] += 1
    assert kinds["bare"] == pytest.approx(60, abs=20) and kinds["mismatched"] == pytest.approx(60, abs=20)
    assert {e.noise for e in episodes} == {0.0, 0.05}
    assert sum(e.noise > 0 for e in episodes) == pytest.approx(150, abs=30)
    with pytest.raises(ValueError, match="must be non-negative and sum to 1"):
        PromptMix(0.5, 0.5, 0.5)


def test_the_drawers_plan_cycles_its_targets_over_the_objects():
    task = DrawerTask().with_options(objects="train", n_objects=3)
    episodes = task.plan_demos(2 * 3 * len(task.objects), seed=0)
    targets = [e.reset_options["target"] for e in episodes]
    assert targets[:3] == [task.objects[0]] * 3 and targets[3:6] == [task.objects[1]] * 3
    assert set(targets) == set(task.objects)
    assert all(f"the {e.reset_options['target']} is in" in fact for e in episodes for fact in e.facts)


def test_the_generic_plan_draws_kinds_and_leaves_the_facts_to_the_task():
    episodes = plan_episodes(200, seed=3, noise=0.1, noisy_fraction=0.25, mix=PromptMix(0.5, 0.5, 0.0))
    assert [e.seed for e in episodes] == list(range(3, 203))
    assert {e.prompt_kind for e in episodes} == {"bare", "matching"}
    assert all(e.facts is None and not e.reset_options for e in episodes)
    assert sum(e.noise > 0 for e in episodes) == pytest.approx(50, abs=20)
    assert plan_episodes(200, seed=3, noise=0.1, noisy_fraction=0.25, mix=PromptMix(0.5, 0.5, 0.0)) == episodes
    with pytest.raises(ValueError, match="episodes must be >= 1"):
        plan_episodes(0)
    with pytest.raises(ValueError, match="unknown prompt kind 'true'"):
        DemoEpisode(1, "true")
    with pytest.raises(ValueError, match="a bare prompt carries no facts"):
        DemoEpisode(1, "bare", facts=("the cube is in drawer layer 1.",))


def test_a_prompt_mix_is_read_from_kind_shares_and_a_bad_one_is_named():
    mix = PromptMix.parse("bare=0.2, matching=0.5,mismatched=0.15,recalled=0.15")
    assert mix == PromptMix(0.2, 0.5, 0.15, 0.15) and PromptMix.parse("matching=1") == PromptMix(0.0, 1.0, 0.0)
    for bad, message in (("bare=0.2,true=0.8", "bad prompt mix entry 'true=0.8'"),
                         ("matching=lots", "bad prompt mix share 'lots' for 'matching'"),
                         ("bare=0.5", "must be non-negative and sum to 1")):
        with pytest.raises(ValueError, match=message):
            PromptMix.parse(bad)
    # a recalled share of 0 leaves the other kinds' draws as they were before the kind existed
    old = plan_episodes(50, seed=4, mix=PromptMix(0.2, 0.6, 0.2))
    assert [e.prompt_kind for e in old] == [e.prompt_kind for e in plan_episodes(50, seed=4)]
    kinds = [e.prompt_kind for e in plan_episodes(400, seed=4, mix=mix)]
    assert kinds.count("recalled") == pytest.approx(60, abs=20)
    with pytest.raises(ValueError, match="a recalled prompt's facts follow what the writer reads"):
        DemoEpisode(1, "recalled", facts=("the cue cube was red.",))
    with pytest.raises(ValueError, match="give its share to matching"):
        DrawerTask().plan_demos(6, mix=mix)


def test_the_task_words_the_facts_of_an_unnamed_kind(recorder):
    recorded = recorder.record(DemoEpisode(3, "matching", reset_options={"target_layer": 2}))
    assert recorded.prompt == prompt_of(at(3, 2, 2)) and recorded.group == "2" and recorded.success


def test_a_frame_never_reveals_the_closed_drawers_cube(recorder):
    recorded = recorder.record(at(3, 2, 2))
    seen = states(recorded)
    assert recorded.success and len(seen) == len(recorded.actions) < 400
    visible = seen[:, DETECTION][:, 0] > 0.5
    assert not visible[0] and visible[-1]
    assert np.all(seen[~visible, DETECTION] == 0.0)  # zeros until the drawer is open: no layer leak
    assert np.abs(recorded.actions).max() <= 1.0 + 1e-6


def test_empty_named_drawer_ends_the_episode_once_the_expert_idles(recorder):
    recorded = recorder.record(at(4, 3))
    assert not recorded.success and len(recorded.actions) < 400
    assert np.all(recorded.actions[-16:, :6] == pytest.approx(0.0, abs=0.05))  # holding still
    assert recorder.task.expert_gave_up(recorder.expert)


def test_dagger_frames_follow_the_learner_with_the_experts_labels():
    class Stubborn(ScriptedDrawerController):
        """A learner that always heads for the top drawer, whatever its prompt says."""

        def act(self, obs, prompts, check_prompts=True):
            return super().act(obs, [INSTRUCTION] * len(prompts))

    dagger = DemoRecorder(DrawerTask(), "none", learner=Stubborn())
    try:
        recorded = dagger.record(at(5, 3, 3))
    finally:
        dagger.env.close()
    assert recorded.learner_acted and not recorded.success
    # the learner opened the top drawer, yet the labels keep asking for the bottom one
    seen = states(recorded)
    opening_1 = seen[:, STATE_NAMES.index("opening_1")]
    assert opening_1.max() > 0.2
    labels_dz = recorded.actions[:40, 2].sum()
    learner_obs_z = seen[:40, STATE_NAMES.index("tcp_z")]
    assert labels_dz < 0 and learner_obs_z[-1] > learner_obs_z[0] - 0.05


def test_recorded_dataset_reads_back_with_lerobot(tmp_path):
    episodes = [at(11, 1, 1), at(12, 2, noise=0.05)]
    out = record_demos(tmp_path / "demos", "drawer", episodes, max_steps=60)
    dataset = read_dataset(out)
    assert dataset.num_episodes == 2 and dataset.fps == 20 and dataset.meta.robot_type == "panda_light"
    assert set(dataset.meta.tasks.index) == {prompt_of(e) for e in episodes}
    frame = dataset[0]
    assert frame["observation.state"].shape == (19,) and frame["action"].shape == (7,)
    assert frame["task"] == prompt_of(episodes[0])
    log = read_episode_log(out)
    assert [r["seed"] for r in log] == [11, 12] and [r["frames"] for r in log] == [60, 60]
    assert log[0]["reset_options"] == {"target_layer": 1, "target": "cube"} and log[0]["group"] == "1"
    assert log[0]["task"] == "drawer" and log[1]["prompt"] == INSTRUCTION
    with pytest.raises(FileExistsError, match="already exists"):
        record_demos(out, "drawer", episodes)


def test_interrupted_recording_keeps_saved_episodes(tmp_path):
    episodes = [at(20 + k, 1) for k in range(3)]

    def interrupt(frames):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        record_demos(tmp_path / "demos", "drawer", episodes, max_steps=24, on_episode=interrupt)
    assert read_dataset(tmp_path / "demos").num_episodes == 1


def test_cameras_are_recorded_under_the_libero_keys(tmp_path):
    out = record_demos(tmp_path / "demos", "drawer", [at(30, 2, 2)], render_backend="cpu", max_steps=9)
    frame = read_dataset(out)[8]
    for key in IMAGE_KEYS:
        assert frame[key].shape == (3, 224, 224) and float(frame[key].std()) > 0.01


def test_decision_frames_carry_the_labels_of_their_chunk(recorder):
    episode = at(3, 2, 2)
    every = recorder.record(episode)
    by_decision = DemoRecorder(DrawerTask(), "none", frames="decisions")
    try:
        decisions = by_decision.record(episode)
    finally:
        by_decision.env.close()
    assert len(decisions.actions) == len(every.actions)  # the same episode, labelled at every step
    np.testing.assert_allclose(decisions.actions, every.actions, atol=1e-3)  # (contacts differ in the last bits)
    assert list(decisions.frame_steps) == list(range(0, len(every.actions), 8))
    np.testing.assert_allclose(states(decisions), states(every)[::8], atol=1e-2)
    chunks, pad = decisions.chunks(32)
    np.testing.assert_array_equal(chunks[1], decisions.actions[8:40])
    left = len(decisions.actions) - decisions.frame_steps[-1]
    assert not pad[-1, :left].any() and pad[-1, left:].all()
    with pytest.raises(ValueError, match="unknown frames 'some'"):
        DemoRecorder(DrawerTask(), "none", frames="some")


def test_decision_frames_render_only_where_a_controller_acts(tmp_path):
    from sb3_memret.controllers.observation import ACTION_CHUNK_KEY, CHUNK_PAD_KEY

    out = record_demos(tmp_path / "demos", "drawer", [at(30, 2, 2)], render_backend="cpu", max_steps=17,
                       frames="decisions", image_size=48)
    dataset = read_dataset(out)
    assert len(dataset) == 3 and read_episode_log(out)[0]["steps"] == 17  # steps 0, 8 and 16 of 17
    frame = dataset[2]
    assert frame[ACTION_CHUNK_KEY].shape == (32, 7) and int(frame[CHUNK_PAD_KEY].sum()) == 31
    for key in IMAGE_KEYS:
        assert frame[key].shape == (3, 48, 48) and float(frame[key].std()) > 0.01


def test_an_image_size_above_the_rendered_one_is_refused():
    with pytest.raises(ValueError, match=r"image_size must be in \[16, 224\] \(task 'drawer'"):
        DemoRecorder(DrawerTask(), "cpu", image_size=256)

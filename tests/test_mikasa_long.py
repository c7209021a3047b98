"""MIKASA's -Long cue tasks (600 steps): registered with their short task's class, MIKASA's horizon and wrapper
table, and an expert that leaves the cue alone and still succeeds after the long delay."""

import numpy as np
import pytest
import torch

from mikasa_support import MIKASA_MISSING

pytest.importorskip("mikasa_robo_suite.vla.memory_envs", reason=MIKASA_MISSING)

from sb3_memret.controllers.prompts import build_prompt  # noqa: E402
from sb3_memret.tasks import make_task, task_names  # noqa: E402
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask, is_long  # noqa: E402

LONG = [name for name in task_names() if is_long(name) and name.startswith("Remember")]  # the cue family's


def test_the_nine_long_variants_are_registered_with_their_short_tasks_class():
    assert sorted(LONG) == sorted(
        [f"RememberColor{n}-Long-VLA-v0" for n in (3, 5, 9)] + [f"RememberShape{n}-Long-VLA-v0" for n in (3, 5, 9)]
        + [f"RememberShapeAndColor{n}-Long-VLA-v0" for n in ("3x2", "3x3", "5x3")])
    for name in LONG:
        long, short = make_task(name), make_task(name.replace("-Long-VLA-v0", "-VLA-v0"))
        assert type(long) is type(short) and long.words == short.words and long.name == name
        assert long.max_control_steps == 600 and not long.noop_before_manipulation
        assert long.expert().wait_for_all and not short.expert().wait_for_all


def test_horizons_and_noop_wrappers_are_mikasas():
    """Every cue-family task's horizon is its env's registered one, and it takes the no-op wrapper exactly where
    MIKASA's wrapper table (apply_mikasa_vla_wrappers) gives it one."""
    import gymnasium as gym
    from mikasa_robo_suite.vla.utils.apply_wrappers import VLA_WRAPPER_CONFIGS

    cue_tasks = [name for name in task_names()
                 if name.startswith(("Remember", "FindImposter", "BunchOf", "SeqOf", "ChainOf", "BlinkCount"))]
    # Remember{Color,Shape,ShapeAndColor} x 3 sizes, their -Long, FindImposter x 9, the 18 colour-cue tasks and the
    # 6 BlinkCount
    assert len(cue_tasks) == 27 + 18 + 6
    for name in cue_tasks:
        task = make_task(name)
        assert isinstance(task, MikasaCueTask)
        assert task.max_control_steps == gym.spec(name).max_episode_steps, name
        assert task.noop_before_manipulation == (VLA_WRAPPER_CONFIGS[name].curriculum_wrapper is not None), name


def test_the_expert_waits_at_its_ready_pose_while_the_cue_shows():
    """RememberColor3-Long with the oracle prompt: no wrapper freezes the arm, yet through the cue phase (10-100
    steps) the hand stays away from the cue cube at the table centre, and success does not come from touching it."""
    task = make_task("RememberColor3-Long-VLA-v0")
    env = task.make_env(obs_mode="state_dict", sim_backend="cpu", robot_uids="panda")
    expert = task.expert()
    try:
        from mikasa_robo_suite.vla.utils.wrappers import CurriculumPhaseNoopActionWrapper

        wrapper, chain = env, []
        while hasattr(wrapper, "env"):
            chain.append(type(wrapper))
            wrapper = wrapper.env
        assert CurriculumPhaseNoopActionWrapper not in chain
        obs, info = env.reset(seed=5000)
        base = env.unwrapped
        colour = task.episode(task.frames(env, obs, info, reset=True)[0]).group
        prompt = build_prompt(task.instruction_text, [task.cue_fact.format(colour=colour)], task.template)
        expert.reset([5000])
        cue = int(base.cue_steps_per_env[0])
        assert cue >= 10
        for step in range(min(cue, 40)):
            if step % 4 == 0:
                chunk = expert.act(obs, [prompt])[0]
            obs, _, _, _, info = env.step(torch.from_numpy(chunk[step % 4][None]).float())
            tcp = obs["extra"]["tcp_pose"][0, :3].numpy()
            assert np.linalg.norm(tcp - np.array([0.0, 0.0, 0.02])) > 0.08 and not bool(info["success"][0]), step
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["RememberColor9-Long-VLA-v0", "RememberShapeAndColor5x3-Long-VLA-v0"])
def test_the_expert_succeeds_after_the_long_delay_and_only_with_the_right_fact(name):
    """Whole 600-step episodes at two development seeds: the oracle fact succeeds after a delay of 50-450 steps (the
    arm held at its ready pose does not drift off), the wrong one does not."""
    task = make_task(name)
    env = task.make_env(obs_mode="state_dict", sim_backend="cpu", robot_uids="panda")
    expert = task.expert()
    try:
        for seed, condition in ((5000, "oracle"), (5001, "wrong")):
            obs, info = env.reset(seed=seed)
            episode = task.episode(task.frames(env, obs, info, reset=True)[0])
            facts = task.oracle_facts(episode) if condition == "oracle" else task.wrong_facts(episode)
            prompt = build_prompt(task.instruction(episode), facts, task.prompt_template)
            expert.reset([seed])
            success, first = False, None
            for step in range(600):
                if step % 4 == 0:
                    chunk = expert.act(obs, [prompt])[0]
                obs, _, _, _, info = env.step(torch.from_numpy(chunk[step % 4][None]).float())
                if bool(info["success"][0]) and first is None:
                    first = step
                success |= bool(info["success"][0])
            appear = int(env.unwrapped.cue_steps_per_env[0] + env.unwrapped.empty_steps_per_env[0])
            assert success == (condition == "oracle"), (seed, condition)
            assert first is None or first >= appear
    finally:
        env.close()

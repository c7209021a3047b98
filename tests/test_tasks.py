"""A memory task of a user's own, written only against the public Task interface, trains end to end.

``DoorsTask``: a light flashes one of three colours at the start of an episode; later the robot (a
point on a line) must stop at the door of that colour. The writer sees the light at every step, the
bank holds decoys worded like its fact, and the expert goes to the door its prompt's fact names.
"""

from __future__ import annotations

import json
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np
import click
import pytest
from click.testing import CliRunner

from sb3_memret.cli import main
from sb3_memret.controllers.base import ControllerSpec, FrozenController
from sb3_memret.envs.vec_env import make_recall_vec_env
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.policy.ppo import MemRetPPO
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.rewards import absorbing_success_value
from sb3_memret.tasks import EnvFrame, Episode, Predicates, Task, make_task, register_task, task_names

COLOURS = ("red", "green", "blue")
DOORS = np.array([-1.0, 0.0, 1.0])
INSTRUCTION = "go to the door of the light."
FACT = "the {entity} was {colour}."
LIGHT_KEY = (MemoryType.OTHER, "light", "was")


class DoorsEnv(gym.Env):
    """x in [-1.5, 1.5]; action: a velocity in [-1, 1] (0.25 per step); the light shows its colour at step 0 only."""

    control_mode, obs_mode = "velocity", "state"

    def __init__(self, max_episode_steps: int = 24):
        self.max_steps = max_episode_steps
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = gym.spaces.Dict({"x": gym.spaces.Box(-2, 2, (1,)), "light": gym.spaces.Box(0, 1, (3,))})

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.colour, self.x, self.t = int(self.np_random.integers(3)), 0.0, 0
        return self._obs(), self._info()

    def step(self, action):
        self.x = float(np.clip(self.x + 0.25 * float(np.asarray(action).reshape(-1)[0]), -1.5, 1.5))
        self.t += 1
        info = self._info()
        return self._obs(), -abs(self.x - DOORS[self.colour]), bool(info["success"]), self.t >= self.max_steps, info

    def _obs(self) -> dict[str, np.ndarray]:
        light = np.eye(3, dtype=np.float32)[self.colour] if self.t == 0 else np.zeros(3, np.float32)
        return {"x": np.array([self.x], np.float32), "light": light}

    def _info(self) -> dict[str, Any]:
        return {"success": abs(self.x - DOORS[self.colour]) < 0.05 and self.t > 2}


class LightWriter:
    relations = {"light": (MemoryType.OTHER, "was")}

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        return [(step, {("light", "light"): c}) for step, c in frame.timed_percepts() if c is not None]


class DoorsExpert(FrozenController):
    """Goes to the door of the colour its prompt's fact names (any fact worded so), holds still without one."""

    stateful = False

    def __init__(self):
        self.spec = ControllerSpec("velocity", chunk_len=4, action_dim=1,
                                   prompt_template=PromptTemplate((INSTRUCTION,), (FACT,)))

    def reset(self, seeds: Sequence[int]) -> None:
        pass

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        pass

    def _act(self, obs, prompts, parsed) -> np.ndarray:
        chunks = np.zeros((len(prompts), 4, 1), np.float32)
        for i, prompt in enumerate(parsed):
            if prompt.facts:
                colour = dict(prompt.facts[0].fields)["colour"]
                goal = DOORS[COLOURS.index(colour)] if colour in COLOURS else float(obs["x"][i, 0])
                chunks[i, :, 0] = np.clip((goal - float(obs["x"][i, 0])) / 0.25, -1, 1)
        return chunks


class DoorsTask(Task):
    name = "doors-test"
    perceives_every_step = True
    max_control_steps = 24

    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, **kwargs: Any) -> gym.Env:
        return DoorsEnv(max_episode_steps or self.max_control_steps)

    def env_kwargs(self, needs_images: bool, render_backend: str) -> dict[str, Any]:
        return {}

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        batched = {key: np.asarray(value)[None] for key, value in obs.items()}
        return [EnvFrame(batched, {"colour": COLOURS[env.unwrapped.colour]}, None, bool(info["success"]))]

    def perceive(self, env: gym.Env, obs: Any) -> str | None:
        return COLOURS[int(np.argmax(obs["light"]))] if obs["light"].any() else None

    def writer(self, source: str = "seeded") -> LightWriter:
        return LightWriter()

    def episode(self, frame: EnvFrame) -> Episode:
        return Episode("light", frame.state["colour"], ((LIGHT_KEY, frame.state["colour"]),))

    def seed_memories(self, frame, episode, rng, seeding: SeedingConfig, facts: bool = True) -> list[MemoryEntry]:
        words = rng.choice(sorted(seeding.vocabulary), size=seeding.location_decoys, replace=False)
        return [MemoryEntry.create(MemoryType.OTHER, str(w), "was", str(rng.choice(COLOURS)), 0) for w in words]

    @property
    def prompt_template(self) -> PromptTemplate:
        return PromptTemplate((INSTRUCTION,), (FACT,))

    def instruction(self, episode: Episode) -> str:
        return INSTRUCTION

    def oracle_facts(self, episode: Episode) -> list[str]:
        return [FACT.format(entity="light", colour=episode.group)]

    def wrong_facts(self, episode: Episode) -> list[str]:
        return [FACT.format(entity="light", colour=COLOURS[(COLOURS.index(episode.group) + 1) % 3])]

    def expert(self) -> DoorsExpert:
        return DoorsExpert()


if DoorsTask.name not in task_names():
    register_task(DoorsTask.name, DoorsTask)


def test_a_registered_task_is_made_by_name_and_unknown_names_are_listed():
    assert isinstance(make_task("doors-test"), DoorsTask)
    with pytest.raises(ValueError, match="unknown task 'nope'; expected one of .*'drawer'.*'doors-test'"):
        make_task("nope")
    with pytest.raises(ValueError, match="already registered"):
        register_task("drawer", DoorsTask)


def test_the_writer_sees_a_cue_shorter_than_a_replan(encoder):
    venv = make_recall_vec_env(1, {"task": "doors-test", "controller": "scripted", "encoder": encoder,
                                   "replan_every": 4, "location_decoys": 3, "capacity": 4}, seed=0)
    venv.reset()
    memory = venv.venv.memories[0]
    assert sum(e.text.startswith("the light was") for e in memory.bank.entries) == 1  # seen at the reset frame
    assert memory.true_slot() >= 0
    _, _, _, infos = venv.step(np.array([[memory.true_slot()]]))
    assert infos[0]["retrieved_true"] and infos[0]["group"] in COLOURS
    venv.close()


def test_options_a_task_does_not_implement_are_refused(encoder):
    with pytest.raises(ValueError, match="task 'doors-test' does not implement \\['household', 'observed'\\]"):
        make_recall_vec_env(1, {"task": "doors-test", "controller": "scripted", "encoder": encoder,
                                "long_term_capacity": 2, "memory_source": "observed"})
    with pytest.raises(ValueError, match="does not implement \\['observe_potential'\\]"):  # it has no potential
        make_recall_vec_env(1, {"task": "doors-test", "controller": "scripted", "encoder": encoder,
                                "observe_potential": True})


def test_the_memory_learner_trains_on_a_task_of_its_own(encoder):
    """PPO learns to retrieve the light's fact among decoys worded alike, from the env's own reward."""
    kwargs = {"task": DoorsTask(), "controller": "scripted", "encoder": encoder, "replan_every": 4,
              "location_decoys": 3, "capacity": 4}
    venv = make_recall_vec_env(1, kwargs, seed=0)
    model = MemRetPPO(env=venv, n_steps=64, batch_size=32, gae_lambda=0.7, learning_rate=3e-3, seed=0)
    from sb3_memret.evaluation.retrieval import evaluate_retrieval

    before = evaluate_retrieval(model, venv, 20, seed=1000)
    model.learn(1536)
    after = evaluate_retrieval(model, venv, 20, seed=1000)
    venv.close()
    assert after.greedy_accuracy >= 0.9 > before.greedy_accuracy
    assert after.success["overall"] >= 0.9
    assert set(after.success) <= {"overall", *COLOURS}


class AbsorbingDoorsTask(DoorsTask):
    """The doors, ending at success (the env already does) as a task whose env would run on in success paying 0.5."""

    ends_at_success, success_reward = True, 0.5


def _oracle_decisions(task: Task, encoder) -> tuple[list[float], list[int], bool]:
    """One oracle episode decided to its end, replanning every 3 steps: each decision's reward and the episode's
    steps after it. Its light is an outer door's (4 steps away), so success comes 1 step into the second decision."""
    venv = make_recall_vec_env(1, {"task": task, "controller": "scripted", "encoder": encoder, "mode": "oracle",
                                   "replan_every": 3, "location_decoys": 3, "capacity": 4}, seed=0)
    env = venv.venv
    env.set_task_seeds([[next(seed for seed in range(100) if _colour_of(seed) != "green")]])
    env.reset_envs([0])
    rewards, steps, done = [], [], False
    while not done:
        _, reward, terminated, truncated, infos = env.decide(np.zeros((1, 1), dtype=np.int64))
        rewards.append(float(reward[0]))
        steps.append(int(env.episode_steps[0]))
        done = bool(terminated[0] or truncated[0])
    venv.close()
    return rewards, steps, bool(infos[0]["success"])


def test_a_success_that_ends_the_episode_earns_the_steps_it_cut_off(encoder):
    plain, steps, success = _oracle_decisions(DoorsTask(), encoder)
    absorbing, _, _ = _oracle_decisions(AbsorbingDoorsTask(), encoder)
    assert success and steps == [3, 4]
    assert absorbing[:-1] == plain[:-1]  # only the decision that succeeds earns more
    cut_off = absorbing_success_value(0.5, DoorsTask.max_control_steps - 4, 2, 3, 0.97)
    assert cut_off > 0 and absorbing[-1] == pytest.approx(plain[-1] + cut_off, rel=1e-5)


def test_a_task_that_ends_at_success_must_say_what_success_pays(encoder):
    class Unpriced(DoorsTask):
        ends_at_success = True

    with pytest.raises(ValueError, match="task 'doors-test' ends its episodes at success but sets no success_reward"):
        make_recall_vec_env(1, {"task": Unpriced(), "controller": "scripted", "encoder": encoder})


class SeededDoorsTask(DoorsTask):
    """The doors with a benchmark protocol: its test set 4242424242 + i, development seeds 5000 + i."""

    def evaluation_seeds(self, n_episodes: int) -> list[int]:
        return [4242424242 + i for i in range(n_episodes)]

    def development_seeds(self, n_episodes: int) -> list[int]:
        return [5000 + i for i in range(n_episodes)]


def test_evaluation_plays_the_tasks_development_seeds_once_each_and_its_test_set_only_by_name(encoder):
    from sb3_memret.evaluation.retrieval import evaluate_retrieval
    from sb3_memret.evaluation.rollout import evaluate_task_condition

    venv = make_recall_vec_env(2, {"task": SeededDoorsTask(), "controller": "scripted", "encoder": encoder,
                                   "replan_every": 4, "location_decoys": 3, "capacity": 4}, backend="inprocess")
    model = MemRetPPO(env=venv, n_steps=8, batch_size=8, seed=0)
    played = []
    report = evaluate_retrieval(model, venv, 5, seed=3, on_episode=played.append)
    assert sorted(e["task_seed"] for e in played) == [5000 + i for i in range(5)]
    for episode in played:  # the seed decides the light, as MIKASA's seeds decide its cue
        assert episode["group"] == _colour_of(episode["task_seed"])
    assert report.episodes == 5 and venv.task_seed_queues == [[], []]  # later episodes draw seeds again
    tested = []
    evaluate_retrieval(model, venv, 2, seed=3, on_episode=tested.append, held_out="evaluation")
    assert sorted(e["task_seed"] for e in tested) == [4242424242, 4242424243]
    rollouts = {kind: [r.seed for r in evaluate_task_condition(DoorsExpert(), "oracle", SeededDoorsTask(), 2, seed=7,
                                                                replan_every=4, held_out=kind)]
                for kind in ("development", "evaluation", None)}
    assert rollouts == {"development": [5000, 5001], "evaluation": [4242424242, 4242424243], None: [7, 8]}
    with pytest.raises(ValueError, match="unknown held-out seed kind 'test'"):
        evaluate_task_condition(DoorsExpert(), "oracle", SeededDoorsTask(), 1, held_out="test")
    explicit = []
    evaluate_retrieval(model, venv, 3, seed=3, on_episode=explicit.append, task_seeds=[11, 12, 13])
    assert sorted(e["task_seed"] for e in explicit) == [11, 12, 13]
    with pytest.raises(ValueError, match="4 episodes need as many task seeds, got 3"):
        evaluate_retrieval(model, venv, 4, task_seeds=[1, 2, 3])
    with pytest.raises(ValueError, match="task seeds must be integers in \\[0, 2\\*\\*32\\)"):
        venv.set_task_seeds([[-1], []])
    venv.close()


def _colour_of(seed: int) -> str:
    env = DoorsEnv()
    env.reset(seed=seed)
    return COLOURS[env.colour]


def test_the_cli_runs_a_task_class_named_by_module_path():
    """``--task module:Class`` runs a task of one's own without registering it; a bad path says what failed."""
    runner = CliRunner()
    result = runner.invoke(main, ["rollout", "--task", f"{__name__}:DoorsTask", "--controller", "scripted",
                                  "--episodes", "6", "--replan-every", "4", "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output.strip().splitlines()[-1])
    assert summary["success"]["overall"] == 1.0 and set(summary["success"]) <= {"overall", *COLOURS}
    result = runner.invoke(main, ["rollout", "--task", f"{__name__}:Missing"])
    assert result.exit_code == 2 and f"cannot import 'Missing' from module '{__name__}'" in result.output


class PairDoorsEnv(DoorsEnv):
    """Two lights, shown at steps 0 and 1; the door to stop at is the one ``(first + second) % 3`` counts to,
    so both facts are needed."""

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        gym.Env.reset(self, seed=seed)
        self.colour, self.second, self.x, self.t = *(int(c) for c in self.np_random.integers(3, size=2)), 0.0, 0
        return self._obs(), self._info()

    @property
    def door(self) -> int:
        return (self.colour + self.second) % 3

    def _obs(self) -> dict[str, np.ndarray]:
        shown = {0: self.colour, 1: self.second}.get(self.t)
        light = np.eye(3, dtype=np.float32)[shown] if shown is not None else np.zeros(3, np.float32)
        return {"x": np.array([self.x], np.float32), "light": light, "which": np.array([float(self.t)], np.float32)}

    def _info(self) -> dict[str, Any]:
        return {"success": abs(self.x - DOORS[self.door]) < 0.05 and self.t > 2}


class PairWriter:
    relations = {"light": (MemoryType.OTHER, "was")}

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        return [(step, {("light", entity): c}) for step, (entity, c) in frame.timed_percepts() if c is not None]


class PairDoorsExpert(DoorsExpert):
    """Goes to door ``(first + second) % 3`` of the prompt's two light facts; holds still without both."""

    def _act(self, obs, prompts, parsed) -> np.ndarray:
        chunks = np.zeros((len(prompts), 4, 1), np.float32)
        for i, prompt in enumerate(parsed):
            seen = {dict(f.fields)["entity"]: dict(f.fields)["colour"] for f in prompt.facts}
            if {"first light", "second light"} <= set(seen) and {seen["first light"], seen["second light"]} <= set(COLOURS):
                goal = DOORS[(COLOURS.index(seen["first light"]) + COLOURS.index(seen["second light"])) % 3]
                chunks[i, :, 0] = np.clip((goal - float(obs["x"][i, 0])) / 0.25, -1, 1)
        return chunks


class PairDoorsTask(DoorsTask):
    """The doors with two facts to remember: a retrieval is right only with both (K = 2)."""

    name = "pair-doors-test"

    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, **kwargs: Any) -> gym.Env:
        return PairDoorsEnv(max_episode_steps or self.max_control_steps)

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        batched = {key: np.asarray(value)[None] for key, value in obs.items()}
        colours = (COLOURS[env.unwrapped.colour], COLOURS[env.unwrapped.second])
        return [EnvFrame(batched, {"colours": colours}, None, bool(info["success"]))]

    def perceive(self, env: gym.Env, obs: Any) -> tuple[str, str | None]:
        entity = "first light" if obs["which"][0] == 0 else "second light"
        return entity, COLOURS[int(np.argmax(obs["light"]))] if obs["light"].any() else None

    def writer(self, source: str = "seeded") -> PairWriter:
        return PairWriter()

    def episode(self, frame: EnvFrame) -> Episode:
        first, second = frame.state["colours"]
        keys = [(MemoryType.OTHER, f"{which} light", "was") for which in ("first", "second")]
        return Episode("light", first, ((keys[0], first), (keys[1], second)))

    def oracle_facts(self, episode: Episode) -> list[str]:
        return [FACT.format(entity=f"{which} light", colour=value)
                for which, (_, value) in zip(("first", "second"), episode.true_facts)]

    def expert(self) -> PairDoorsExpert:
        return PairDoorsExpert()


def pair_doors_env(encoder):
    """The pair-doors recall env with both facts and 2 decoys in a bank of 4, K = 2, the scripted controller."""
    return make_recall_vec_env(1, {"task": PairDoorsTask(), "controller": "scripted", "encoder": encoder,
                                   "replan_every": 4, "location_decoys": 2, "capacity": 4, "k": 2}, seed=0)


def test_a_retrieval_counts_only_with_every_needed_fact_in_the_bank_and_hits_only_with_all(encoder):
    """Two facts needed: the reset decision is not scored (the second light is not yet seen), later ones are, and
    a hit needs both facts among the K = 2 retrieved; one of them and a decoy is a miss, and the expert holds still."""
    venv = pair_doors_env(encoder)
    venv.reset()
    memory = venv.venv.memories[0]
    assert len(memory.true_slots()) == 1 and not memory.facts_in_bank() and memory.true_slot() == -1
    decoy = next(i for i, e in enumerate(memory.slot_entries()) if not memory.is_true(e))
    _, _, _, infos = venv.step(np.array([[memory.true_slots()[0], decoy]]))
    assert infos[0]["decision_true_slots"] == [] and not infos[0]["retrieved_true"]
    both = memory.true_slots()
    assert len(both) == 2 and memory.facts_in_bank() and memory.true_slot() == both[0]
    _, _, _, infos = venv.step(np.array([[both[0], decoy]]))
    assert sorted(infos[0]["decision_true_slots"]) == sorted(both) and not infos[0]["retrieved_true"]
    _, _, _, infos = venv.step(np.array([both[::-1]]))
    assert infos[0]["retrieved_true"] and infos[0]["true_slots"] == sorted(both)
    venv.close()


def test_the_memory_learner_learns_to_retrieve_every_needed_fact(encoder):
    """K = 2 over 2 facts and 2 decoys: a uniform draw holds both 1 time in 6; PPO, at the paper's settings and
    with one Plackett-Luce draw per episode (the default), learns to hold both within 1024 decisions and keeps it
    for 1024 more (seeds 0-3; ``lab/2026-11-26-exploration-stability/exploration_stability.py``)."""
    from sb3_memret.evaluation.retrieval import evaluate_retrieval

    venv = pair_doors_env(encoder)
    model = MemRetPPO(env=venv, n_steps=64, batch_size=32, gae_lambda=0.7, seed=0)
    before = evaluate_retrieval(model, venv, 20, seed=1000, samples=200)
    assert before.sampled_fraction == pytest.approx(1 / 6, abs=0.1)
    learned = []
    for _ in range(2):
        model.learn(1024, reset_num_timesteps=False)
        learned.append(evaluate_retrieval(model, venv, 20, seed=1000))
    venv.close()
    assert before.greedy_accuracy < 0.9
    assert all(after.greedy_accuracy >= 0.9 and after.success["overall"] >= 0.9 for after in learned)


def test_a_decision_can_hold_its_prompt_for_several_replans(encoder):
    """``replans_per_decision`` R: each decision executes R replans (R controller calls) with one prompt, sums the
    env's reward over them, and a decision cut short by the episode's end stops there."""
    kwargs = {"task": DoorsTask(), "controller": "scripted", "encoder": encoder, "replan_every": 2,
              "location_decoys": 3, "capacity": 4}
    one = make_recall_vec_env(1, kwargs, seed=0)
    three = make_recall_vec_env(1, {**kwargs, "replans_per_decision": 3}, seed=0)
    with pytest.raises(ValueError, match="replans_per_decision must be >= 1, got 0"):
        make_recall_vec_env(1, {**kwargs, "replans_per_decision": 0})
    one.reset(), three.reset()
    decoy = next(i for i, e in enumerate(one.venv.memories[0].slot_entries()) if not one.venv.memories[0].is_true(e))
    rewards_one = [float(one.step(np.array([[decoy]]))[1][0]) for _ in range(3)]  # the decoy: the expert goes astray
    _, reward_three, _, infos = three.step(np.array([[decoy]]))
    assert three.unwrapped.controller_calls == 3 and one.unwrapped.controller_calls == 3
    assert three.venv.memories[0].t == one.venv.memories[0].t == 6
    assert float(reward_three[0]) == pytest.approx(sum(rewards_one), rel=1e-5)
    five = make_recall_vec_env(1, {**kwargs, "replans_per_decision": 5}, seed=0)  # 10 steps a decision
    five.reset()
    memory = five.venv.memories[0]
    astray = next(i for i, e in enumerate(memory.slot_entries()) if e.value != memory.truth.group)
    dones = [bool(five.step(np.array([[astray]]))[2][0]) for _ in range(3)]
    assert dones == [False, False, True]  # the 24-step episode ends 4 steps (2 replans) into the third decision
    assert five.unwrapped.controller_calls == 5 + 5 + 2
    five.close()
    one.close(), three.close()


class LateLightEnv(DoorsEnv):
    """The light flashes at step 3, in the middle of a decision, instead of at the reset."""

    def _obs(self) -> dict[str, np.ndarray]:
        light = np.eye(3, dtype=np.float32)[self.colour] if self.t == 3 else np.zeros(3, np.float32)
        return {"x": np.array([self.x], np.float32), "light": light}


class LateLightTask(DoorsTask):
    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, **kwargs: Any) -> gym.Env:
        return LateLightEnv(max_episode_steps or self.max_control_steps)


@pytest.mark.parametrize("on_write", [False, True])
def test_a_decision_ends_when_its_writer_adds_a_fact_if_asked(encoder, on_write):
    """``retrieve_on_write``: a decision of up to 5 replans (of 2 steps) ends after the replan in which the light was
    seen (steps 3-4), so the next retrieval can pick the new fact; without it the decision runs its 10 steps."""
    venv = make_recall_vec_env(1, {"task": LateLightTask(), "controller": "scripted", "encoder": encoder,
                                   "replan_every": 2, "replans_per_decision": 5, "retrieve_on_write": on_write,
                                   "location_decoys": 3, "capacity": 4}, seed=0)
    venv.reset()
    memory = venv.venv.memories[0]
    assert memory.true_slot() < 0  # nothing seen yet
    venv.step(np.array([[0]]))
    assert memory.true_slot() >= 0
    assert (venv.unwrapped.controller_calls, memory.t) == ((2, 4) if on_write else (5, 10))
    astray = next(i for i, e in enumerate(memory.slot_entries()) if e is not None and e.value != memory.truth.group)
    venv.step(np.array([[astray]]))  # no new fact (and no success to end the episode): the whole decision
    assert (venv.unwrapped.controller_calls, memory.t) == ((7, 14) if on_write else (10, 20))
    venv.close()


def test_a_run_whose_task_cannot_be_made_here_is_refused_in_one_line(tmp_path):
    """A saved run of a task of one's own, read where its module is not on PYTHONPATH: every command that reads the
    run names it, the task and why, in one line, with no traceback."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yml").write_text("mine:\n  n_timesteps: 16\n  env_kwargs:\n    task: nomodule:Thing\n"
                                    "    mode: recall\n    capacity: 6\n    k: 1\n")
    for args in (["report", str(run)], ["train", "recall", "--resume", "--out", str(run)]):
        result = CliRunner().invoke(main, args)
        assert result.exit_code == 1 and "Traceback" not in result.output, result.output
        assert f"the run in {str(run)!r} cannot be read here" in result.output and "'nomodule'" in result.output
    from sb3_memret.cli.options import saved_task

    with pytest.raises(click.ClickException, match="plays task 'nomodule:Thing', which cannot be made here"):
        saved_task("nomodule:Thing", run)

"""sb3-memret's agent as a policy of MIKASA's harness: writer, bank, retriever and the frozen controller.

MIKASA's ``run_episode`` asks a policy for actions with ``forward(obs)`` whenever its action queue is empty. The
agent declares ``chunk_size = 1``, so the harness calls it at every control step: every frame reaches the writer
(a cue can be shorter than a replan), and the agent replans its frozen controller every ``replan_every`` steps
itself, returning that chunk's actions one per call. What the controller's prompt carries is the condition's:

- ``none``: the instruction alone; ``oracle``: with the task's true facts; ``wrong``: with facts worded alike that
  name something else (``Task.oracle_facts`` / ``wrong_facts``: the only condition-side use of the ground truth);
- ``written``: with every fact the task's writer wrote from the cameras so far, no decoys, no retriever (checks the
  writer end to end);
- ``recall``: with the facts a trained memory learner retrieves from a bank holding the writer's facts and the
  task's decoys (its run's settings: capacity, K, decoys, age unit), greedily, its retention critic evicting.

What each part reads (``sb3_memret.benchmark.view``): the writer, the bank, the retriever and a controller on the
harness's inputs see the harness's observation alone (``policy_view``); a controller that reads more (the scripted
experts' detector, a camera policy's joint velocities) gets a ``PrivilegedView`` and its rows are an upper bound. The
agent holds the env behind a ``SimulatorGuard``: while it acts, only the benchmark's own reads (the episode's truth,
the stated instruction, a privileged controller's view) reach the simulator, and any other read fails. The recall
condition's decoys come from the agent's own generator (``seed``, and the episode's place in the run), never from the
episode's seed.

The instruction is the task's; where each episode's is the one its env states (``Task.instruction_in_info``: MIKASA's
Rotate names the angle to turn in ``info["language_instruction"]``), the agent asks the env for it at the episode's
first step (``stated_instruction``), as the harness keeps the reset's info from its policy.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import gymnasium as gym
import numpy as np

from sb3_memret.benchmark.guard import SimulatorGuard, benchmark_reads
from sb3_memret.benchmark.view import PrivilegedView, policy_view
from sb3_memret.controllers.base import FrozenController
from sb3_memret.controllers.pacing import replan_interval
from sb3_memret.controllers.prompts import build_prompt
from sb3_memret.tasks.base import EnvFrame, Episode, Task

if TYPE_CHECKING:
    from sb3_memret.evaluation.rollout import FactSchedule

CONDITIONS = ("none", "oracle", "wrong", "written", "recall")


def check_conditions(conditions: Sequence[str]) -> list[str]:
    """``conditions`` if each is a benchmark condition, without repeats; else a ValueError naming the bad one."""
    unknown = [c for c in conditions if c not in CONDITIONS]
    if unknown or not conditions:
        raise ValueError(f"unknown conditions {unknown}; expected a comma list of {list(CONDITIONS)}")
    return list(dict.fromkeys(conditions))


def short_variant(env_id: str) -> str | None:
    """A -Long variant's short task (``RememberColor3-Long-VLA-v0`` -> ``RememberColor3-VLA-v0``), else None."""
    return env_id.replace("-Long-VLA-v0", "-VLA-v0") if env_id.endswith("-Long-VLA-v0") else None


def learned_as(env_id: str, trained_on: Sequence[str]) -> str | None:
    """The task among a learner's ``trained_on`` that serves ``env_id``: itself, or for a -Long variant its short
    task (the bank holds the same facts, worded alike, under the same instruction; only the delay before they are
    needed grows, which is what the -Long row measures); None when neither was trained."""
    if env_id in trained_on:
        return env_id
    short = short_variant(env_id)
    return short if short in trained_on else None


class MemoryLearner:
    """A trained memory learner (``sb3-memret train recall``'s model) and the bank settings of its run (for a
    learner across tasks, those ``task`` played with)."""

    def __init__(self, path: Path, controller: str, task: str | None = None):
        from sb3_memret.envs.multi_task import task_env_kwargs
        from sb3_memret.policy.ppo import load_model
        from sb3_memret.training.run import eval_env_kwargs

        self.path = Path(path)
        self.model = load_model(self.path)
        self.settings = eval_env_kwargs(self.model, self.path, "recall", controller, "cpu")
        if "tasks" in self.settings:  # a learner across tasks: the settings ``task`` played with
            per_task = task_env_kwargs(self.settings)
            served = learned_as(task, list(per_task)) if task is not None else None
            if served is None:
                raise ValueError(f"{self.path}: a learner across tasks {list(per_task)}, not trained on {task!r} "
                                 "nor on the short task of a -Long variant")
            self.settings = per_task[served]
        if self.settings.get("observe_potential"):
            raise ValueError(f"{self.path}: a learner whose critic observes the shaping potential reads simulator "
                             "state at run time; the benchmark's agent may read cameras and proprioception only")
        if self.settings.get("long_term_capacity") or any(
                store.get("timescale") == "lasting" for store in self.settings.get("stores") or ()):
            raise ValueError(f"{self.path}: a household learner (long-term store) is not a MIKASA task's learner")

    def keep_scores(self, entries: Sequence[Any], ages: np.ndarray, timescale: int | None) -> np.ndarray:
        """The run's retention critic's keep-scores of one store's entries (the lowest is evicted when it is full)."""
        return self.model.policy.retention.score_entries(entries, ages, timescale)

    def retrieve(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """The slots the learner retrieves, greedily (top-K by score)."""
        slots, _ = self.model.predict(dict(observation), deterministic=True)
        return np.asarray(slots).reshape(-1)


class RecalledFacts:
    """The recall condition's facts (a ``sb3_memret.evaluation.rollout.FactSchedule``): what ``learner`` retrieves at each
    decision from a bank that the task's writer fills and its decoys seed (the learner's run settings), its retention
    critic evicting; then, on a task with progress as memory, what the robot has done so far."""

    def __init__(self, task: Task, learner: MemoryLearner, template: Any, encoder: Any,
                 rng: np.random.Generator):
        from sb3_memret.envs.configs import MemoryConfig
        from sb3_memret.envs.recall_memory import EpisodeMemory
        from sb3_memret.memory.seeding import SeedingConfig

        settings = learner.settings
        seeding = dataclasses.replace(SeedingConfig(), **{k: settings[k] for k in ("location_decoys", "holding_decoys", "event_every")
                                                          if settings.get(k) is not None})
        self.learner, self.rng = learner, rng
        if settings.get("stores"):
            config = MemoryConfig(source=settings.get("memory_source", "seeded"), seeding=seeding,
                                  stores=tuple(settings["stores"]))
        else:
            config = MemoryConfig(settings["capacity"], source=settings.get("memory_source", "seeded"),
                                  age_unit=settings["age_unit"], seeding=seeding)
        self.memory = EpisodeMemory(config, "recall", encoder, learner.keep_scores, template, task)

    def start(self, frame: EnvFrame, episode: Episode) -> None:
        self.memory.start(frame, self.rng)

    def observe(self, frame: EnvFrame) -> None:
        self.memory.observe(frame)

    def facts(self, decision: int) -> list[str]:
        """The retrieved facts, then the progress written so far (``EpisodeMemory.prompt_facts``)."""
        return self.memory.prompt_facts(self.memory.choose(self.learner.retrieve(self.memory.observation())))


class MemoryAgent:
    """MIKASA's ``ChunkPolicy`` for one condition: ``bind`` it to a task's harness env, ``begin`` each episode
    with its place in the run, then let the harness call ``forward``. ``seed`` seeds the agent's own generator
    (the recall condition's decoys, the controller's reset)."""

    chunk_size = 1

    def __init__(self, task: Task, controller: FrozenController, condition: str, replan_every: int | None,
                 learner: MemoryLearner | None = None, encoder: Any = None, render_every_step: bool = False,
                 seed: int = 0):
        check_conditions([condition])
        replan_every = replan_interval(task, replan_every, controller)
        if condition == "recall" and learner is None:
            raise ValueError("the recall condition needs a trained memory learner")
        self.task, self.controller, self.condition = task, controller, condition
        self.writes = condition in ("written", "recall")  # the writer's facts reach the prompt
        self.replan_every, self.learner = replan_every, learner
        self.render_every_step = render_every_step  # else only the observations read (``SensorGate``)
        self._gate: Any = None
        self._window: int | None = None  # the task's perception window in this env (``Task.perception_window``)
        self._encoder = encoder
        self.seed = int(seed)
        self.env: SimulatorGuard | None = None
        self._privileged: PrivilegedView | None = None
        self._episode_rng: np.random.Generator | None = None
        self._queue: list[np.ndarray] = []
        self._steps = 0
        self.schedule: "FactSchedule | None" = None
        self.decisions = 0
        self.episode: Episode | None = None
        self.prompts: list[str] = []  # the prompts of the current episode's decisions, in order

    # ------------------------------------------------------------ set-up
    @property
    def encoder(self) -> Any:
        if self._encoder is None:
            from sb3_memret.memory.encoder import MiniLMEncoder

            self._encoder = MiniLMEncoder()
        return self._encoder

    def bind(self, env: gym.Env) -> None:
        """Act in ``env`` (a harness env of this agent's task) from now on, held behind a ``SimulatorGuard``."""
        from sb3_memret.physics.sensor_gate import SensorGate

        self.env, self._privileged = SimulatorGuard(env), None
        self.controller.check_env(env)
        self._gate = SensorGate.of(env)
        self._window = self.task.perception_window(env) if self.task.perceives_every_step else None

    def begin(self, episode: int) -> None:
        """The next ``forward`` starts the run's ``episode``-th episode (its generator: the agent's seed and it)."""
        if self.env is None:
            raise RuntimeError("bind() the agent to its harness env before an episode")
        self._episode_rng = np.random.default_rng([self.seed, int(episode)])
        self._queue, self._steps = [], 0
        self._gate.open, self._gate.cameras = True, None  # the reset's observation starts the episode

    # ------------------------------------------------------------ acting
    def _frame(self, view: Mapping[str, Any], first: bool) -> EnvFrame:
        info: dict[str, Any] = {"success": np.zeros(1, dtype=bool)}
        with benchmark_reads("the episode's truth (metrics, the oracle and wrong conditions) and stated instruction"):
            if first and self.task.instruction_in_info:
                info["language_instruction"] = stated_instruction(self.env)
            frame, = self.task.frames(self.env, view, info, reset=first)
        frame.steps = 0 if first else 1
        if self._perceives(self._steps):
            frame.percepts = [self.task.perceive(self.env, view)]
        return frame

    def _perceives(self, step: int) -> bool:
        """Whether the writer perceives the observation after ``step`` control steps: where the condition writes
        facts, at every step of the task's perception window."""
        return self.writes and self.task.perceives_every_step and (self._window is None or step < self._window)

    def _start(self, frame: EnvFrame) -> None:
        from sb3_memret.evaluation.rollout import condition_schedule

        self.episode, self.prompts, self.decisions = self.task.episode(frame), [], 0
        self.controller.reset([int(self._episode_rng.integers(2**31))])
        self.schedule = RecalledFacts(self.task, self.learner, self.controller.spec.prompt_template, self.encoder,
                                      self._episode_rng) if self.condition == "recall" else \
            condition_schedule(self.task, self.condition)
        self.schedule.start(frame, self.episode)

    def forward(self, obs: Mapping[str, Any]) -> np.ndarray:
        """The next action (7,) for the harness's observation (its ``rgb`` and ``proprio`` only are read)."""
        if self._episode_rng is None:
            raise RuntimeError("begin(episode) the episode before the harness calls forward()")
        with self.env.armed():
            return self._act(obs)

    def _act(self, obs: Mapping[str, Any]) -> np.ndarray:
        view = policy_view(obs)
        first = self._steps == 0
        frame = self._frame(view, first)
        if first:
            self._start(frame)
        else:
            self.schedule.observe(frame)
        if not self._queue:
            prompt = build_prompt(self.task.instruction(self.episode), self.schedule.facts(self.decisions),
                                  self.controller.spec.prompt_template)
            self.decisions += 1
            self.prompts.append(prompt)
            chunk = self.controller.act(self._controller_view(obs, view), [prompt])[0][:self.replan_every]
            self._queue = [np.asarray(action, dtype=np.float32) for action in chunk]
        self._steps += 1
        action = self._queue.pop(0)
        self._gate.open, self._gate.cameras = self._next_render()
        return action

    def _controller_view(self, obs: Mapping[str, Any], view: Mapping[str, Any]) -> Mapping[str, Any]:
        """The controller's observation: the policy side's view for a controller on the harness's inputs, else the
        privileged one (the benchmark reads the simulator for it; its rows are labelled an upper bound)."""
        if self.controller.spec.harness_inputs:
            return view
        with benchmark_reads("a privileged controller's view"):
            if self._privileged is None:
                self._privileged = PrivilegedView(self.task, self.env, obs)
            return self._privileged.observation(obs)

    def _next_render(self) -> tuple[bool, frozenset[str] | None]:
        """Whether the next observation's images are rendered, and which cameras (None: every one): all of them by
        the controller at a decision, while it reads them (``FrozenController.reads_images``), and where the
        condition writes facts, at decisions for a task that does not perceive every step or whose frames read the
        images (``Task.frames_read_images``); the writer's cameras alone (``Task.writer_cameras``) at the other steps
        of its task's perception window."""
        decides = not self._queue
        frames_read = self.writes and (not self.task.perceives_every_step or self.task.frames_read_images)
        if self.render_every_step or (decides and (self.controller.reads_images() or frames_read)):
            return True, None
        if self._perceives(self._steps):
            cameras = self.task.writer_cameras
            return True, None if cameras is None else frozenset(cameras)
        return False, None


def stated_instruction(env: gym.Env) -> Any:
    """The instruction MIKASA's env states for the episode under way, ``info["language_instruction"]`` (one per env).
    The harness keeps the reset's info from its policy, so the env is asked for its info again (``get_info``, which
    evaluates the state the reset left, unchanged) and that key alone is kept: the protocol's policy inputs are the
    images, proprioception and the instruction, never the rest of the info (``oracle_info``, ``task_cue``)."""
    return env.unwrapped.get_info()["language_instruction"]


__all__ = ["CONDITIONS", "MemoryAgent", "MemoryLearner", "RecalledFacts", "check_conditions", "learned_as",
           "short_variant", "stated_instruction"]

"""The Task interface: what one memory task hands the toolkit, and nothing else.

Everything else (bank, encoder, retriever, retention, PPO, the decision VecEnv, physics backends,
evaluation) is task-agnostic and reaches the task only through this class:

- **simulation**: ``make_env`` builds the task's gymnasium env (ManiSkill or not) and ``frames``
  says what a reset or an executed chunk left in each env of a batch (``EnvFrame``); with
  ``perceives_every_step`` the physics also calls ``perceive`` after every control step, so a
  cue shorter than a replan still reaches the writer;
- **the writer**: ``writer()`` turns frames into predicates, which the ``EventCompiler``
  compiles into typed facts (``relations`` says which memory type each predicate becomes);
- **the prompt contract**: ``prompt_template`` (what the controller was trained on),
  ``instruction``, ``oracle_facts`` and ``wrong_facts`` (``facts_at``: as they read at a step);
- **decoys**: ``seed_memories``, the bank at t = 0;
- **ground truth, for metrics only**: ``episode(frame)`` (never an input of the policy or the
  controller);
- **the expert**: ``expert()``, the frozen controller that records demonstrations and serves as
  ``--controller scripted``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, ClassVar, Mapping, Protocol

import gymnasium as gym
import numpy as np

from sb3_memret.memory.schema import Key, MemoryEntry, MemoryType
from sb3_memret.memory.writer import Predicates
from sb3_memret.common.obs_trees import select_obs, to_numpy
from sb3_memret.controllers.prompts import ParsedPrompt

if TYPE_CHECKING:
    from sb3_memret.tasks.ablations import AblationBuilder
    from sb3_memret.tasks.demos import DemoEpisode, PromptMix
    from sb3_memret.memory.seeding import SeedingConfig


class Household(Protocol):
    """One env's world across a household's episodes: where things are, kept or rearranged between episodes."""

    def next_episode(self, rng: np.random.Generator) -> tuple[dict[str, Any], str, bool]:
        """The next episode's placement, its target, and whether the household was rearranged."""

RENDER_BACKENDS = ("none", "cpu", "gpu")


@dataclass
class EnvFrame:
    """One task env after a reset or an executed chunk.

    ``obs`` is the controller's observation with a batch dimension of one (numpy arrays in the
    env's nested layout); ``state`` whatever the task's writer and ``episode`` read (privileged:
    never a controller's input); ``potential`` the task's shaping potential (None: the decision
    reward is the env's own, ``reward``, summed over the chunk); ``success`` whether the episode
    has succeeded at any step so far (success once); ``percepts`` what ``Task.perceive`` read at
    each control step of the chunk (the reset frame's: at the reset), for tasks that perceive every
    step. ``views`` and ``look_in``: what a camera sees of each object now and in the observation
    phase (the drawer's observed memory).
    """

    obs: dict[str, Any]
    state: Any
    potential: float | None
    success: bool
    steps: int = 0  # control steps the chunk executed (0 after a reset)
    terminated: bool = False
    truncated: bool = False
    views: np.ndarray | None = None
    look_in: np.ndarray | None = None
    reward: float = 0.0  # the env's own reward summed over the executed steps
    percepts: list[Any] = field(default_factory=list)

    def timed_percepts(self) -> list[tuple[int, Any]]:
        """Each percept with its control step counted from the chunk's start: the reset frame's at 0,
        a chunk's j-th after step j + 1 (what a per-step writer's ``read`` answers with)."""
        first = 0 if self.steps == 0 else 1
        return [(first + j, percept) for j, percept in enumerate(self.percepts)]


@dataclass(frozen=True)
class Episode:
    """What the task knows of one episode, for metrics only.

    ``target`` is the entity the instruction names; ``group`` the bucket success is reported by
    (the drawer's layer, a cue's colour); ``true_facts`` the (key, value) pairs of the memories
    the controller needs; ``details`` extra task-specific info copied into the decision env's info.
    """

    target: str
    group: str
    true_facts: tuple[tuple[Key, str], ...]
    details: Mapping[str, Any] = field(default_factory=dict)

    def is_true(self, entry: MemoryEntry) -> bool:
        """Whether ``entry`` is one of the memories the controller needs."""
        return (entry.key, entry.value) in self.true_facts


class Writer(Protocol):
    """The rule-based writer's reading side: frames in, predicates keyed (relation, entity) out."""

    relations: Mapping[str, tuple[MemoryType, str]]

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        """Predicates read from ``frame``, each with its control step counted from the chunk's start
        (the reset frame's at 0)."""


class Task(ABC):
    """One memory task family. Subclass it, give it a ``name``, and ``register_task`` it (or hand an
    instance to ``make_recall_vec_env(env_kwargs={"task": ...})``); instances must pickle, as physics
    worker processes receive them."""

    name: ClassVar[str]
    #: the zoo config file (under zoo_configs/) and its section key for ``sb3-memret train``
    zoo_config: ClassVar[str] = "memret_ppo.yml"
    #: decision-env options beyond the generic ones that this task implements
    features: ClassVar[frozenset[str]] = frozenset()
    #: the task's own options (``with_options``), set in a run's ``env_kwargs`` beside the decision env's
    options: ClassVar[tuple[str, ...]] = ()
    #: whether the physics calls ``perceive`` after every control step (else frames carry no percepts)
    perceives_every_step: ClassVar[bool] = False
    #: the cameras ``perceive`` reads (``sensor_data`` names): on a step only the writer reads, the benchmark renders
    #: these alone and the others carry their last images (MIKASA's writers read the calibrated base camera); None:
    #: every camera
    writer_cameras: ClassVar[tuple[str, ...] | None] = ("base_camera",)
    #: whether ``frames`` reads the camera images (SeqOfColors' progress writer reads the cube layout there): then
    #: every decision's frame must carry images rendered for it, also where no controller reads images
    frames_read_images: bool = False
    #: the render backend a run gets when none is named: "none" unless the task itself must see
    default_render_backend: ClassVar[str] = "none"
    max_control_steps: int = 400
    #: control steps between two controller calls when a command is not told otherwise (``--replan-every``, a
    #: config's ``replan_every``)
    replan_every: ClassVar[int] = 8
    #: whether an episode ends at its first success: success counts once, so the steps after it cannot change
    #: the figure (for envs that run on after success, as MIKASA's SeqOfColors does for its 400 steps)
    ends_at_success: ClassVar[bool] = False
    #: for a task that ends at success: the env's reward at each step once it has succeeded (what the cut-off
    #: steps would have paid, ``sb3_memret.tasks.rewards.absorbing_success_value``); required with ``ends_at_success``
    success_reward: ClassVar[float | None] = None
    #: whether each episode's instruction is the one its env states in the reset's ``info["language_instruction"]``
    #: (MIKASA's Rotate names a new angle every episode there): ``frames`` reads it from the reset's info, and
    #: MIKASA's harness, which keeps the reset's info from its policy, is asked for that key (``benchmark.agent``)
    instruction_in_info: ClassVar[bool] = False
    #: what the groups success is reported by are called in a table (``Episode.group``; the drawer's: its layers)
    group_name: ClassVar[str] = "group"
    #: the task's own wording of some facts, (type, value) -> template (the drawer: an object out of its drawers)
    wordings: ClassVar[Mapping[tuple[MemoryType, str], str]] = {}

    @property
    def config_key(self) -> str:
        """The section of ``zoo_config`` that holds this task's hyperparameters."""
        return self.name

    # ------------------------------------------------------------ simulation
    @abstractmethod
    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, **kwargs: Any) -> gym.Env:
        """The task's env (with every wrapper its protocol applies); ``kwargs`` from ``env_kwargs``."""

    @abstractmethod
    def env_kwargs(self, needs_images: bool, render_backend: str) -> dict[str, Any]:
        """The obs mode and render backend a controller (reading images or not) needs, checked."""

    @abstractmethod
    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        """One frame per env of the batch after a reset or a step (steps, reward, percepts and
        success-once are filled in by the physics)."""

    def perceive(self, env: gym.Env, obs: Any) -> Any:
        """What the writer needs of one control step's observation, read where the physics runs
        (small and picklable: it crosses process boundaries). Only with ``perceives_every_step``."""
        raise NotImplementedError(f"{type(self).__name__} does not perceive every step")

    def perception_window(self, env: gym.Env) -> int | None:
        """With ``perceives_every_step``: how many control steps from the reset can show the writer anything (a
        cue's longest phase); after them it perceives nothing, and the cameras render only for the controller's
        decisions. None: the whole episode. Read from the env's settings, never from an episode's draw, so it holds
        for every episode of ``env``."""
        return None

    # ------------------------------------------------------------ memory
    @abstractmethod
    def writer(self, source: str = "seeded") -> Writer:
        """A new writer for one env's episodes (``source``: where facts come from, if the task has several)."""

    @abstractmethod
    def episode(self, frame: EnvFrame) -> Episode:
        """The ground truth of the episode a reset frame starts (metrics only)."""

    @abstractmethod
    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: "SeedingConfig",
                      facts: bool = True) -> list[MemoryEntry]:
        """The bank at t = 0, in a random order: decoys as ``seeding`` says, and with ``facts`` the facts
        the task hands over at the start (the drawer's seeded memory; a task that must observe them
        writes them from its frames instead)."""

    # ------------------------------------------------------------ a household's episodes (long-term memory)
    def new_household(self) -> "Household":
        """One env's household: what stays in place from one episode to the next (``features`` "household")."""
        raise NotImplementedError(f"task {self.name!r} has no households (Task.new_household)")

    def hearsay(self, rng: np.random.Generator, now: int, seeding: "SeedingConfig") -> list[MemoryEntry]:
        """Facts about other things a household's long-term store hears each episode, at time ``now`` (decoys it
        must learn to let go of); none by default."""
        return []

    def event_decoy(self, rng: np.random.Generator, now: int, seeding: "SeedingConfig") -> MemoryEntry:
        """One event decoy at time ``now`` (``SeedingConfig.event_every``): a thing of ``seeding``'s vocabulary seen in
        passing, worded as the controller's prompts word such a fact; a task that words none refuses the option."""
        raise ValueError(f"task {self.name!r} words no event decoys (Task.event_decoy); leave event_every at 0")

    def look_in(self, frame: EnvFrame, rng: np.random.Generator, household: bool) -> Predicates:
        """The observation phase of the ``observed`` variant (``features`` "observed"): predicates of what the robot
        saw at the reset (``EnvFrame.look_in``), everywhere it looks, or with ``household`` only where this episode's
        glimpses fall."""
        raise NotImplementedError(f"task {self.name!r} has no observation phase (Task.look_in)")

    def timescale(self, entry: MemoryEntry) -> str:
        """The timescale ``entry`` matters at, which picks its store (``sb3_memret.memory.stores``): ``"lasting"``
        for what outlives an episode (the drawer: where an object was seen in a drawer), ``"now"`` for what holds
        only at the moment (what the robot holds, a failure just seen), ``"episode"`` for the rest."""
        if entry.type in (MemoryType.HOLDING, MemoryType.FAILURE):
            return "now"
        return "episode"

    # ------------------------------------------------------------ prompts
    @property
    @abstractmethod
    def prompt_template(self) -> Any:
        """The ``PromptTemplate`` of the controllers this task's prompts are checked against."""

    @property
    def instruction_templates(self) -> tuple[str, ...]:
        """The instructions a controller trained on this task's demonstrations may take, with fields where its
        demonstrations vary them (the drawer's ``pick out the {entity}.``: any object word); the finetune keeps the
        ones its datasets hold. By default the prompt template's."""
        return tuple(self.prompt_template.instructions)

    @abstractmethod
    def instruction(self, episode: Episode) -> str:
        """The instruction of ``episode``, as the controller was trained on it."""

    @abstractmethod
    def oracle_facts(self, episode: Episode) -> list[str]:
        """The fact texts that tell the controller what it must remember (the oracle condition)."""

    @abstractmethod
    def wrong_facts(self, episode: Episode) -> list[str]:
        """Fact texts worded as the true ones but naming something else (the wrong condition)."""

    def facts_at(self, condition: str, episode: Episode, t: int) -> list[str]:
        """The oracle's or the wrong condition's facts ``t`` control steps into ``episode``, where every prompt of a
        fixed condition takes them: ``oracle_facts`` or ``wrong_facts``, the same at every step, unless the task's
        facts carry a time (TimedTransfer's ``the lamp turned green 96 steps ago.``)."""
        if condition not in ("oracle", "wrong"):
            raise ValueError(f"condition {condition!r} has no facts of its own; expected 'oracle' or 'wrong'")
        return self.oracle_facts(episode) if condition == "oracle" else self.wrong_facts(episode)

    def facts_now(self, condition: str, episode: Episode, frame: EnvFrame, t: int) -> list[str]:
        """The oracle's or the wrong condition's facts at ``frame``, ``t`` control steps into ``episode``: ``facts_at``'s,
        unless the facts follow what the robot has done (BatteriesChecker's checklist: the batteries it has checked)."""
        return self.facts_at(condition, episode, t)

    def progress_facts(self, frame: EnvFrame) -> list[str]:
        """What the robot has done by ``frame``, worded as this task's progress writer words it, from the
        simulator's state (privileged). Every fixed condition (oracle, wrong, none) carries it, so a controller that
        reads its progress from its prompt is measured on the cue's memory alone. Empty for a task without progress."""
        return []

    # ------------------------------------------------------------ controllers
    @abstractmethod
    def expert(self) -> Any:
        """The scripted expert, a ``FrozenController`` that obeys its prompt."""

    # ------------------------------------------------------------ demonstrations
    def plan_demos(self, n: int, seed: int = 0, noise: float = 0.0, noisy_fraction: float = 0.5,
                   mix: "PromptMix | None" = None) -> list["DemoEpisode"]:
        """The ``n`` demonstrations ``sb3-memret demos`` records from env seed ``seed`` on: prompt kinds drawn by
        ``mix``, ``noisy_fraction`` of them with arm noise ``noise`` (``sb3_memret.tasks.demos.plan_episodes``); a
        task that chooses its episodes' groups (the drawer's layers) plans them itself."""
        from sb3_memret.tasks.demos import plan_episodes

        return plan_episodes(n, seed, noise, noisy_fraction, mix)

    def expert_gave_up(self, expert: Any) -> bool:
        """Whether the task's expert (``expert()``, batch 1) holds still for good, having found that its prompt leads
        nowhere (the drawer's: the named drawer was empty); a recording ends after a few such steps. Never, by
        default."""
        return False

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        """The LeRobotDataset feature spec of one demonstration frame: what a learned controller may see
        (``observation.state``, cameras with ``with_images``) and its ``action``."""
        raise NotImplementedError(f"task {self.name!r} defines no demonstration layout (Task.demo_features)")

    def demo_frame(self, obs: Any, with_images: bool) -> dict[str, np.ndarray]:
        """One frame of a batch-1 controller observation, in ``demo_features``' layout."""
        raise NotImplementedError(f"task {self.name!r} defines no demonstration layout (Task.demo_frame)")

    def state_names(self) -> tuple[str, ...]:
        """The names of ``demo_features``' state entries: the layout a learned controller's state comes from."""
        from sb3_memret.controllers.observation import STATE_KEY

        return tuple(self.demo_features(False)[STATE_KEY]["names"])

    def proprio_names(self) -> tuple[str, ...]:
        """The state entries a real robot reads of itself (joints, hand pose, gripper): all a camera-reading
        controller may take besides its cameras; the rest (object detectors, drawer openings) is simulator state."""
        raise NotImplementedError(f"task {self.name!r} does not say which of its state entries are proprioception "
                                  "(Task.proprio_names)")

    def hand_position_names(self) -> tuple[str, ...]:
        """The state entries that place the hand (x, y, z, in the frame of the objects' positions): where a
        demonstration's hand ends says which object it was about (``finetune``'s pointer hindsight)."""
        raise NotImplementedError(f"task {self.name!r} does not say which of its state entries place the hand "
                                  "(Task.hand_position_names)")

    def controller_inputs(self, obs: Any, n_envs: int, with_images: bool) -> dict[str, np.ndarray]:
        """``demo_frame`` of every env of a batched controller observation, stacked: (n_envs, ...) per feature."""
        obs = to_numpy(obs)
        frames = [self.demo_frame(select_obs(obs, i), with_images) for i in range(n_envs)]
        return {key: np.stack([frame[key] for frame in frames]) for key in frames[0]}

    def replan_interval(self, replan_every: int | None, chunk_len: int, whose: str = "the") -> int:
        """The control steps executed from each action chunk: ``replan_every``, or this task's own
        (``replan_every``) when None; refused unless in [1, ``chunk_len``], the chunk length of ``whose`` controller.
        Every command, runner and env resolves it here."""
        replan_every = self.replan_every if replan_every is None else replan_every
        if not 1 <= replan_every <= chunk_len:
            raise ValueError(f"replan_every must be in [1, {chunk_len}] ({whose} chunk length), got {replan_every}")
        return replan_every

    def check_prompt(self, prompt: ParsedPrompt) -> None:
        """Refuse, naming it, a parsed prompt whose values this task has no place for (the drawer: a layer its
        cabinet lacks), before a controller acts on it; the default accepts every prompt the template parses."""

    @property
    def default_controller(self) -> str:
        """The frozen controller a command runs on this task when none is named: the task's shipped camera-reading
        ``learned`` controller where one ships and does the task (not ``LEARNED_NOT_DEFAULT``), else its expert
        (``scripted``)."""
        from sb3_memret.controllers.shipped import LEARNED_NOT_DEFAULT, shipped_names

        learned = "learned" in shipped_names(self.name) and self.name not in LEARNED_NOT_DEFAULT
        return "learned" if learned else "scripted"

    def chosen_groups(self) -> tuple[str, ...]:
        """The groups a command may choose its episodes by (``group_reset_options``; the drawer: its layers), in
        order; none for a task whose env draws every episode's group itself (a cue's colour)."""
        return ()

    def group_reset_options(self, group: str) -> dict[str, Any]:
        """The reset options that play an episode of ``group``, one of ``chosen_groups``; else a ValueError naming
        them."""
        groups = self.chosen_groups()
        if group not in groups:
            accepted = f"one of {list(groups)}" if groups else "none: its env draws every episode's group itself"
            raise ValueError(f"task {self.name!r} has no {self.group_name} {group!r} to choose; expected {accepted}")
        raise NotImplementedError(f"task {type(self).__name__} names groups but no reset options for them")

    def ablations(self) -> Mapping[str, "AblationBuilder"]:
        """The controller ablation tables this task defines, by name (``sb3-memret ablate``; the drawer: the seed
        paper's replan, prompt, memcount and wording tables); none by default."""
        return {}

    def evaluation_seeds(self, n_episodes: int) -> list[int] | None:
        """The env seeds of the task's benchmark protocol for ``n_episodes`` held-out episodes, or None
        (held-out episodes then draw their seeds from the evaluation seed)."""
        return None

    def development_seeds(self, n_episodes: int) -> list[int] | None:
        """The env seeds of ``n_episodes`` held-out episodes for development (training's evaluations, choosing
        checkpoints and variants), disjoint from ``evaluation_seeds``, which give the final figure only; None: the
        evaluation seed decides, as for ``evaluation_seeds``."""
        return None

    def option_checks(self) -> Mapping[str, tuple[type | tuple[type, ...], Callable[[Any], bool], str]]:
        """How a config checks each of ``options`` before the task is made: its type(s), a test of its value, and
        what is accepted, in words (``sb3_memret.training.config``'s form)."""
        return {}

    def with_options(self, **options: Any) -> "Task":
        """This task with its own ``options`` set (the drawer: its objects, its households); an option the task
        does not take is refused, naming it and the ones it takes."""
        unknown = sorted(set(options) - set(self.options))
        if unknown:
            raise ValueError(f"task {self.name!r} has no option {unknown}; its options are "
                             f"{list(self.options) or 'none'}")
        return self

    def check_options(self, **options: Any) -> None:
        """Refuse decision-env options this task does not implement, naming them."""
        unsupported = sorted(name for name, used in options.items() if used and name not in self.features)
        if unsupported:
            raise ValueError(f"task {self.name!r} does not implement {unsupported}; "
                             f"its options are {sorted(self.features) or 'none beyond the generic ones'}")


def check_render_backend(render_backend: str) -> str:
    if render_backend not in RENDER_BACKENDS:
        raise ValueError(f"unknown render backend {render_backend!r}; expected one of {list(RENDER_BACKENDS)}")
    return render_backend


__all__ = ["EnvFrame", "Episode", "Household", "Predicates", "RENDER_BACKENDS", "Task", "Writer", "check_render_backend"]

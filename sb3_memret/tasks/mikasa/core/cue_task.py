"""What MIKASA-Robo-VLA's "remember what was shown once, act on it later" tasks share (RememberColor,
RememberShape, SeqOfColors, TakeItBack).

MIKASA's env with its protocol (``pd_ee_delta_pose``, ``CurriculumPhaseNoopActionWrapper`` where MIKASA
applies it, the ``normalized_dense`` reward, success once, evaluation at seeds 4242424242 + i); a writer
that reads the cue from the base camera at every control step and writes one fact about the cue; decoys
worded like it about other things; the expert reading the cue's word from its prompt. A subclass names the
word (colour, shape, side), its vocabulary, the fact's wording, the reader and the detector view.
"""

from __future__ import annotations

from typing import Any, Callable, ClassVar, Mapping

import gymnasium as gym
import numpy as np

from sb3_memret.controllers.base import as_numpy
from sb3_memret.memory.schema import Key, MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates, Task, check_render_backend
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.touch_expert import ScriptedTouchController

EVAL_SEED = 4242424242  # MIKASA-Robo-VLA's first evaluation seed; episode i plays EVAL_SEED + i
DEV_SEED = 5000  # the first development seed (training's evaluations, choices): never one of the protocol's
EPISODE_STEPS = 25
LONG_EPISODE_STEPS = 600  # MIKASA's -Long-VLA-v0 cue tasks: a cue of 10-100 steps, a delay of 50-450
RENDERER_NEEDED = ("MIKASA's envs need a renderer even without cameras, and this task's writer reads the cue from "
                   "the base camera: pass --render-backend cpu (the software renderer of `make renderer`) or gpu")


def is_long(env_id: str) -> bool:
    """Whether ``env_id`` is one of MIKASA's -Long variants (``RememberColor3-Long-VLA-v0``)."""
    return env_id.endswith("-Long-VLA-v0")


def with_long(env_ids: Mapping[str, int]) -> dict[str, int]:
    """``env_ids`` (short ids and their word counts) and their -Long variants."""
    return {**env_ids, **{env_id.replace("-VLA-v0", "-Long-VLA-v0"): n for env_id, n in env_ids.items()}}


class CueWriter:
    """Writes the cue's fact (``the cue cube was red.``) at the control step the base camera showed it alone."""

    def __init__(self, entity: str, relation: str):
        self.entity = entity
        self.relations = {"cue": (MemoryType.OTHER, relation)}

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        return [(step, {("cue", self.entity): word}) for step, word in frame.timed_percepts() if word is not None]


class MikasaCueTask(Task):
    """A MIKASA task whose memory is one word about a cue shown once (its colour, its shape): the base class to
    subclass for another MIKASA env of the kind (RememberColor, RememberShape, SeqOfColors and TakeItBack subclass it).

    It runs MIKASA's env ``env_id`` with its protocol (above), its writer reads the cue's word from the base camera
    at every control step (``read_cue``) and writes ``cue_fact``, its decoys are worded alike about other things, and
    its expert (``ScriptedTouchController``) touches the object the prompt's word names, guessing the first word
    without one. A subclass sets these ten class attributes (none has a default):

    - ``field``: the fact's field that carries the word (``"colour"``, ``"shape"``): the ``{field}`` of
      ``cue_fact`` and of ``template``'s fact template, and what the expert reads from its prompt;
    - ``detector_key``: the key of the object detector's entries in the controller's observation
      (``extra/{detector_key}_positions``, ``extra/{detector_key}_visible``), as ``observation_wrapper`` writes them;
    - ``truth_attribute``: the attribute of MIKASA's env (``env.unwrapped``) that holds each env's cued candidate
      index (``true_color_indices``); read for metrics only (``Episode``), never by the writer or the controller;
    - ``cue_entity``, ``cue_relation``: the cue fact's entity and relation in memory (its key, with
      ``MemoryType.OTHER``); decoys take the same relation about other entities;
    - ``cue_fact``: the cue's fact, a template with ``{field}`` (``"the cue cube was {colour}."``);
    - ``instruction_text``: the instruction every prompt starts with (MIKASA's, lowercased);
    - ``template``: the ``PromptTemplate`` the controllers were trained on: ``instruction_text`` and a fact template
      that ``cue_fact`` and the decoys match;
    - ``vocabulary``: the words, index i naming MIKASA's candidate i (the order of ``truth_attribute``'s indices and
      of the detector's entries); the first ``n_words`` are in play;
    - ``observation_wrapper``: a ``gym.Wrapper`` class (or any callable env -> env) that cuts MIKASA's observation
      to a controller's view: joints, hand, cameras and the detector (``DetectorObservation``,
      ``ControllerObservation``), never ``oracle_info``.

    It must also override ``read_cue(rgb)`` (the shipped readers: ``read_cue_colour``, ``read_cue_shape``), and
    ``__init__`` to give ``env_id`` and ``n_words`` (with defaults, for ``--task module:Class``). Optional:
    ``noop_before_manipulation`` (default True: MIKASA's ``CurriculumPhaseNoopActionWrapper``, no-op actions during
    the cue and delay phases, as its wrapper table gives the short Remember tasks), and the ``Task`` attributes set
    here: ``max_control_steps`` 25, ``replan_every`` 4, ``zoo_config`` (a section keyed by ``env_id``; a task of
    your own passes its own YAML with ``--config``). An ``env_id`` ending ``-Long-VLA-v0`` sets both
    ``max_control_steps`` (600) and ``noop_before_manipulation`` (False) as MIKASA's -Long variants have them.
    """

    zoo_config = "memret_ppo_mikasa.yml"
    perceives_every_step = True
    default_render_backend = "cpu"
    max_control_steps = EPISODE_STEPS
    replan_every = 4  # a cue lasts 1-5 of 25 steps: MIKASA's zoo settings replan every 4

    field: ClassVar[str]
    detector_key: ClassVar[str]
    truth_attribute: ClassVar[str]
    cue_entity: ClassVar[str]
    cue_relation: ClassVar[str]
    cue_fact: ClassVar[str]
    instruction_text: ClassVar[str]
    template: ClassVar[PromptTemplate]
    vocabulary: ClassVar[tuple[str, ...]]
    observation_wrapper: ClassVar[Callable[[gym.Env], gym.Env]]
    noop_before_manipulation: bool = True

    def __init__(self, env_id: str, n_words: int):
        """The task of MIKASA's env ``env_id`` (its name and config key), with the first ``n_words`` words in play.
        A -Long variant (``is_long``) lasts MIKASA's 600 steps, without the no-op wrapper (its wrapper table gives
        the -Long tasks none)."""
        self.name, self.n_words = env_id, n_words
        if is_long(env_id):
            self.max_control_steps, self.noop_before_manipulation = LONG_EPISODE_STEPS, False

    @property
    def words(self) -> tuple[str, ...]:
        return self.vocabulary[: self.n_words]

    @property
    def cue_key(self) -> Key:
        return (MemoryType.OTHER, self.cue_entity, self.cue_relation)

    def read_cue(self, rgb: np.ndarray) -> str | None:
        """The cue's word in one base-camera frame (H, W, 3), or None when no cue shows alone."""
        raise NotImplementedError(f"{type(self).__name__} must override read_cue (e.g. with read_cue_colour or "
                                  "read_cue_shape of sb3_memret.tasks.mikasa)")

    def evaluation_seeds(self, n_episodes: int) -> list[int]:
        return [EVAL_SEED + i for i in range(n_episodes)]

    def development_seeds(self, n_episodes: int) -> list[int]:
        return [DEV_SEED + i for i in range(n_episodes)]

    # ------------------------------------------------------------ simulation
    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, obs_mode: str = "rgb",
                 render_backend: str = "cpu", **kwargs: Any) -> gym.Env:
        if render_backend in ("cpu", "sapien_cpu"):
            from sb3_memret.common.rendering import use_cpu_renderer

            use_cpu_renderer()
        import mikasa_robo_suite.vla.memory_envs  # noqa: F401  (registers the *-VLA-v0 ids)
        from mikasa_robo_suite.vla.utils.wrappers import CurriculumPhaseNoopActionWrapper

        if max_episode_steps is not None:
            kwargs["max_episode_steps"] = max_episode_steps
        env = gym.make(self.name, num_envs=num_envs, obs_mode=obs_mode, control_mode="pd_ee_delta_pose",
                       render_backend=render_backend, reward_mode="normalized_dense", **kwargs)
        if self.noop_before_manipulation:
            env = CurriculumPhaseNoopActionWrapper(env)
        return type(self).observation_wrapper(env)

    def env_kwargs(self, needs_images: bool, render_backend: str) -> dict[str, Any]:
        """Both of MIKASA's cameras for a controller that reads images; otherwise the base camera alone (the
        writer's; ``robot_uids="panda"``, the same arm without the wrist camera), a third of the render cost."""
        if check_render_backend(render_backend) == "none":
            raise ValueError(f"(task {self.name}) {RENDERER_NEEDED}")
        return {"obs_mode": "rgb", "render_backend": render_backend,
                "robot_uids": "panda_wristcam" if needs_images else "panda"}

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        truth = as_numpy(getattr(env.unwrapped, self.truth_attribute)).reshape(-1)  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        return [EnvFrame(select_obs(obs, i), {self.field: self.words[int(truth[i])]}, None, bool(success[i]))
                for i in range(len(success))]

    def perceive(self, env: gym.Env, obs: Any) -> str | None:
        return self.read_cue(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0])

    def perception_window(self, env: gym.Env) -> int | None:
        """The longest cue phase MIKASA's env can draw (``CUE_PHASE_STEPS``: 1-5 steps, 10-100 in -Long), and one
        step more: no later frame shows the cue."""
        phase = getattr(env.unwrapped, "CUE_PHASE_STEPS", None)
        return None if phase is None else int(max(phase)) + 1

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> CueWriter:
        return CueWriter(self.cue_entity, self.cue_relation)

    def episode(self, frame: EnvFrame) -> Episode:
        word = frame.state[self.field]
        return Episode(self.cue_entity, word, ((self.cue_key, word),), {f"cue_{self.field}": word})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` facts worded as the cue's about other things (``the key was red.``);
        the cue's own fact comes only from what the camera saw, whatever ``facts`` says."""
        vocab = sorted(set(seeding.vocabulary))
        return [MemoryEntry.create(MemoryType.OTHER, str(word), self.cue_relation, str(rng.choice(self.words)), 0)
                for word in rng.choice(vocab, size=seeding.location_decoys, replace=False)]

    # ------------------------------------------------------------ prompts and controllers
    @property
    def prompt_template(self) -> PromptTemplate:
        return self.template

    def instruction(self, episode: Episode) -> str:
        return self.instruction_text

    def oracle_facts(self, episode: Episode) -> list[str]:
        return [self.cue_fact.format(**{self.field: episode.group})]

    def wrong_facts(self, episode: Episode) -> list[str]:
        other = self.words[(self.words.index(episode.group) + 1) % self.n_words]
        return [self.cue_fact.format(**{self.field: other})]

    def expert(self) -> ScriptedTouchController:
        """The touch expert; without a fact it touches the first word's object, a guess (success at chance). Where
        no wrapper freezes the arm in the cue and delay phases it waits at its ready pose until every object is in
        sight: MIKASA's success is not gated on the phase, so touching the cue itself would count."""
        return ScriptedTouchController(vocabulary=self.words, field=self.field, prompt_template=self.template,
                                       key=self.detector_key, default=self.words[0],
                                       wait_for_all=not self.noop_before_manipulation)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.demo_features(self.words, with_images, key=self.detector_key)

    def demo_frame(self, obs: Any, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.demo_frame(obs, with_images, key=self.detector_key)

    def proprio_names(self) -> tuple[str, ...]:
        return demo_layout.proprio_names()

    def hand_position_names(self) -> tuple[str, ...]:
        return demo_layout.HAND_POSITION


__all__ = ["CueWriter", "DEV_SEED", "EPISODE_STEPS", "EVAL_SEED", "LONG_EPISODE_STEPS", "MikasaCueTask",
           "RENDERER_NEEDED", "is_long", "with_long"]

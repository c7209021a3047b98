"""MIKASA-Robo-VLA's RememberShape3-VLA-v0 as an sb3-memret task: the cue's shape must be remembered.

The env is MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``, its
``CurriculumPhaseNoopActionWrapper`` (actions are no-ops during the cue and delay phases), 128x128
cameras, the ``normalized_dense`` reward, success counted once per episode, evaluation at seeds
4242424242 + i.

**Episode:** the cue object (a cube, a sphere or a cylinder, all the same blue and 4 cm across) is
shown alone at the table centre for 1-5 steps, every object is hidden for 1-5 steps, then the three
reappear, shuffled along a row across the table (about 20 cm apart), and the robot must touch the
one of the cue's shape and hold still; episodes last 25 steps.

**Randomisations** (MIKASA's): the cue shape, uniform over the 3; the cue and delay lengths; the
objects' positions (which one stands left, centre, right, and a jitter of about 1 cm); the arm's
initial joints.

**Success:** MIKASA's: the TCP within 5 cm of the cue-shaped object's centre and the robot static,
at any step.

The writer sees every control step: it reads the cue's shape from the base camera's pixels
(``read_cue_shape``: silhouette and shading) and writes ``the cue object was a {shape}.``; the
bank's decoys are worded alike about other things (``the key was a sphere.``). The controller sees
``ShapeControllerObservation`` only (never ``oracle_info``), so the shape reaches it only through
its prompt.
"""

from __future__ import annotations

from typing import Any, Mapping

import gymnasium as gym
import numpy as np

from sb3_memret.controllers.base import as_numpy
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.prompts import PromptTemplate, build_prompt
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates, Task, check_render_backend
from sb3_memret.tasks.mikasa import demo_layout
from sb3_memret.tasks.mikasa.remember_color import EPISODE_STEPS, EVAL_SEED, RENDERER_NEEDED
from sb3_memret.tasks.mikasa.expert import ScriptedTouchController
from sb3_memret.tasks.mikasa.shape_perception import SHAPE_NAMES, ShapeControllerObservation, read_cue_shape

CUE_ENTITY = "cue object"
CUE_RELATION = "was_a"  # linearised "was a": "the cue object was a cube."
CUE_KEY = (MemoryType.OTHER, CUE_ENTITY, CUE_RELATION)
# MIKASA's LANGUAGE_INSTRUCTION in the prompt contract's form (lowercase; it parses as is).
INSTRUCTION = "observe the object's shape, wait, then touch the object of the same shape."
# Like a finetuned VLA it follows the shape word whatever the fact is about: a decoy ("the key was a
# sphere.") misleads it as the wrong cue would, so retrieval has to pick the cue's fact.
FACT_TEMPLATE = "the {entity} was a {shape}."
CUE_FACT = "the cue object was a {shape}."
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,))
SHAPE_TASKS = {"RememberShape3-VLA-v0": 3}  # the reader is calibrated for these only


def shape_prompt(shape: str | None) -> str:
    """The controller's prompt: the instruction, plus the cue fact when ``shape`` is given."""
    facts = [] if shape is None else [CUE_FACT.format(shape=shape)]
    return build_prompt(INSTRUCTION, facts, PROMPT_TEMPLATE)


def shape_expert(n_shapes: int = 3, chunk_len: int = 8) -> ScriptedTouchController:
    """The scripted expert: touches the object whose shape the prompt's fact names; holds still without one."""
    return ScriptedTouchController(chunk_len, vocabulary=SHAPE_NAMES[:n_shapes], field="shape",
                                   prompt_template=PROMPT_TEMPLATE, key="shape")


class ShapeCueWriter:
    """Writes ``the cue object was a {shape}.`` at the control step the base camera showed the cue alone."""

    relations = {"cue": (MemoryType.OTHER, CUE_RELATION)}

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        return [(step, {("cue", CUE_ENTITY): shape}) for step, shape in frame.timed_percepts() if shape is not None]


class RememberShapeTask(Task):
    """MIKASA-Robo-VLA's RememberShape3-VLA-v0: touch the object of the shape shown once, earlier."""

    zoo_config = "memret_ppo_mikasa.yml"
    perceives_every_step = True
    default_render_backend = "cpu"
    max_control_steps = EPISODE_STEPS

    def __init__(self, env_id: str = "RememberShape3-VLA-v0"):
        if env_id not in SHAPE_TASKS:
            raise ValueError(f"unknown or uncalibrated RememberShape task {env_id!r}; expected one of "
                             f"{sorted(SHAPE_TASKS)}")
        self.name, self.n_shapes = env_id, SHAPE_TASKS[env_id]

    def evaluation_seeds(self, n_episodes: int) -> list[int]:
        return [EVAL_SEED + i for i in range(n_episodes)]

    @property
    def shapes(self) -> tuple[str, ...]:
        return SHAPE_NAMES[: self.n_shapes]

    # ------------------------------------------------------------ simulation
    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, obs_mode: str = "rgb",
                 render_backend: str = "cpu", **kwargs: Any) -> gym.Env:
        if render_backend in ("cpu", "sapien_cpu"):
            from sb3_memret.rendering import use_cpu_renderer

            use_cpu_renderer()
        import mikasa_robo_suite.vla.memory_envs  # noqa: F401  (registers the *-VLA-v0 ids)
        from mikasa_robo_suite.vla.utils.wrappers import CurriculumPhaseNoopActionWrapper

        if max_episode_steps is not None:
            kwargs["max_episode_steps"] = max_episode_steps
        env = gym.make(self.name, num_envs=num_envs, obs_mode=obs_mode, control_mode="pd_ee_delta_pose",
                       render_backend=render_backend, reward_mode="normalized_dense", **kwargs)
        return ShapeControllerObservation(CurriculumPhaseNoopActionWrapper(env))

    def env_kwargs(self, needs_images: bool, render_backend: str) -> dict[str, Any]:
        """Both of MIKASA's cameras for a controller that reads images; otherwise the base camera alone (the
        writer's; ``robot_uids="panda"``, the same arm without the wrist camera)."""
        if check_render_backend(render_backend) == "none":
            raise ValueError(f"(task {self.name}) {RENDERER_NEEDED}")
        return {"obs_mode": "rgb", "render_backend": render_backend,
                "robot_uids": "panda_wristcam" if needs_images else "panda"}

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.envs.physics import select_obs, to_numpy

        obs = to_numpy(obs)
        shapes = as_numpy(env.unwrapped.true_shape_indices).reshape(-1)  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        return [EnvFrame(select_obs(obs, i), {"shape": self.shapes[int(shapes[i])]}, None, bool(success[i]))
                for i in range(len(success))]

    def perceive(self, env: gym.Env, obs: Any) -> str | None:
        return read_cue_shape(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0], self.n_shapes)

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> ShapeCueWriter:
        return ShapeCueWriter()

    def episode(self, frame: EnvFrame) -> Episode:
        shape = frame.state["shape"]
        return Episode(CUE_ENTITY, shape, ((CUE_KEY, shape),), {"cue_shape": shape})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` facts worded as the cue's about other things (``the key was a sphere.``);
        the cue's own fact comes only from what the camera saw, whatever ``facts`` says."""
        vocab = sorted(set(seeding.vocabulary))
        return [MemoryEntry.create(MemoryType.OTHER, str(word), CUE_RELATION, str(rng.choice(self.shapes)), 0)
                for word in rng.choice(vocab, size=seeding.location_decoys, replace=False)]

    # ------------------------------------------------------------ prompts and controllers
    @property
    def prompt_template(self) -> PromptTemplate:
        return PROMPT_TEMPLATE

    def instruction(self, episode: Episode) -> str:
        return INSTRUCTION

    def oracle_facts(self, episode: Episode) -> list[str]:
        return [CUE_FACT.format(shape=episode.group)]

    def wrong_facts(self, episode: Episode) -> list[str]:
        other = self.shapes[(self.shapes.index(episode.group) + 1) % self.n_shapes]
        return [CUE_FACT.format(shape=other)]

    def expert(self) -> ScriptedTouchController:
        return shape_expert(self.n_shapes)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.demo_features(self.shapes, with_images, key="shape")

    def demo_frame(self, obs: Any, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.demo_frame(obs, with_images, key="shape")


__all__ = ["CUE_ENTITY", "CUE_FACT", "FACT_TEMPLATE", "INSTRUCTION", "PROMPT_TEMPLATE", "RememberShapeTask",
           "ShapeCueWriter", "shape_expert", "shape_prompt"]

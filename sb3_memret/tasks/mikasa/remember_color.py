"""MIKASA-Robo-VLA's RememberColor3/5/9-VLA-v0 as sb3-memret tasks: the cue's colour must be remembered.

The envs are MIKASA's own (``mikasa-robo-suite``), with its protocol: ``pd_ee_delta_pose``, its
``CurriculumPhaseNoopActionWrapper`` (actions are no-ops during the cue and delay phases), 128x128
cameras, the ``normalized_dense`` reward, success counted once per episode, evaluation at seeds
4242424242 + i.

**Episode:** the cue cube (one of N colours) is shown alone at the table centre for 1-5 steps, all
cubes are hidden for 1-5 steps, then the N cubes reappear, shuffled, and the robot must touch the
one of the cue's colour and hold still; episodes last 25 steps.

**Randomisations** (MIKASA's): the cue colour, uniform over N; the cue and delay lengths; the
cubes' positions; the arm's initial joints.

**Success:** MIKASA's: the TCP within 5 cm of the cue-coloured cube and the robot static, at any step.

The writer sees every control step: it reads the cue's colour from the base camera's pixels
(``read_cue_colour``) and writes ``the cue cube was {colour}.``; the bank's decoys are worded
alike about other things. The controller sees ``ControllerObservation`` only (never
``oracle_info``), so the colour reaches it only through its prompt.
"""

from __future__ import annotations

from typing import Any, Mapping

import gymnasium as gym
import numpy as np

from sb3_memret.controllers.base import as_numpy
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.prompts import PromptTemplate
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates, Task, check_render_backend
from sb3_memret.tasks.mikasa import demo_layout
from sb3_memret.tasks.mikasa.expert import CUE_FACT, INSTRUCTION, PROMPT_TEMPLATE, ScriptedTouchController
from sb3_memret.tasks.mikasa.perception import COLOUR_NAMES, ControllerObservation, read_cue_colour

CUE_ENTITY = "cue cube"
CUE_KEY = (MemoryType.OTHER, CUE_ENTITY, "was")
EVAL_SEED = 4242424242  # MIKASA-Robo-VLA's first evaluation seed; episode i plays EVAL_SEED + i
EPISODE_STEPS = 25
RENDERER_NEEDED = ("MIKASA's envs need a renderer even without cameras, and this task's writer reads the cue from "
                   "the base camera: pass --render-backend cpu (the software renderer of `make renderer`) or gpu")


class CueWriter:
    """Writes ``the cue cube was {colour}.`` at the control step the base camera showed the cue alone."""

    relations = {"cue": (MemoryType.OTHER, "was")}

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        return [(step, {("cue", CUE_ENTITY): colour}) for step, colour in frame.timed_percepts() if colour is not None]


class RememberColorTask(Task):
    """MIKASA-Robo-VLA's RememberColor{3,5,9}-VLA-v0: touch the cube of the colour shown once, earlier."""

    zoo_config = "memret_ppo_mikasa.yml"
    perceives_every_step = True
    default_render_backend = "cpu"
    max_control_steps = EPISODE_STEPS

    def __init__(self, env_id: str = "RememberColor3-VLA-v0"):
        colours = {f"RememberColor{n}-VLA-v0": n for n in (3, 5, 9)}
        if env_id not in colours:
            raise ValueError(f"unknown RememberColor task {env_id!r}; expected one of {sorted(colours)}")
        self.name, self.n_colours = env_id, colours[env_id]

    def evaluation_seeds(self, n_episodes: int) -> list[int]:
        return [EVAL_SEED + i for i in range(n_episodes)]

    @property
    def colours(self) -> tuple[str, ...]:
        return COLOUR_NAMES[: self.n_colours]

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
        return ControllerObservation(CurriculumPhaseNoopActionWrapper(env))

    def env_kwargs(self, needs_images: bool, render_backend: str) -> dict[str, Any]:
        """Both of MIKASA's cameras for a controller that reads images; otherwise the base camera alone (the
        writer's; ``robot_uids="panda"``, the same arm without the wrist camera), a third of the render cost."""
        if check_render_backend(render_backend) == "none":
            raise ValueError(f"(task {self.name}) {RENDERER_NEEDED}")
        return {"obs_mode": "rgb", "render_backend": render_backend,
                "robot_uids": "panda_wristcam" if needs_images else "panda"}

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.envs.physics import select_obs, to_numpy

        obs = to_numpy(obs)
        colours = as_numpy(env.unwrapped.true_color_indices).reshape(-1)  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        return [EnvFrame(select_obs(obs, i), {"colour": self.colours[int(colours[i])]}, None, bool(success[i]))
                for i in range(len(success))]

    def perceive(self, env: gym.Env, obs: Any) -> str | None:
        return read_cue_colour(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0], self.n_colours)

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> CueWriter:
        return CueWriter()

    def episode(self, frame: EnvFrame) -> Episode:
        colour = frame.state["colour"]
        return Episode(CUE_ENTITY, colour, ((CUE_KEY, colour),), {"cue_colour": colour})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` facts worded as the cue's about other things (``the key was red.``);
        the cue's own fact comes only from what the camera saw, whatever ``facts`` says."""
        vocab = sorted(set(seeding.vocabulary))
        return [MemoryEntry.create(MemoryType.OTHER, str(word), "was", str(rng.choice(self.colours)), 0)
                for word in rng.choice(vocab, size=seeding.location_decoys, replace=False)]

    # ------------------------------------------------------------ prompts and controllers
    @property
    def prompt_template(self) -> PromptTemplate:
        return PROMPT_TEMPLATE

    def instruction(self, episode: Episode) -> str:
        return INSTRUCTION

    def oracle_facts(self, episode: Episode) -> list[str]:
        return [CUE_FACT.format(colour=episode.group)]

    def wrong_facts(self, episode: Episode) -> list[str]:
        other = self.colours[(self.colours.index(episode.group) + 1) % self.n_colours]
        return [CUE_FACT.format(colour=other)]

    def expert(self) -> ScriptedTouchController:
        return ScriptedTouchController()

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.demo_features(self.colours, with_images)

    def demo_frame(self, obs: Any, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.demo_frame(obs, with_images)


__all__ = ["CUE_ENTITY", "CueWriter", "EVAL_SEED", "RememberColorTask"]

"""MIKASA-Robo-VLA's TimedTransfer tasks (Easy, Medium, Hard and their -Long) as sb3-memret tasks: how long ago a
lamp turned green must be remembered, to act on a step counted from it.

The temporal-memory tasks with a fact that carries a time. The env is MIKASA's own (``mikasa-robo-suite``), with its
protocol: ``pd_ee_delta_pose``, 128x128 cameras, the ``normalized_dense`` reward, success counted once per episode,
evaluation at seeds 4242424242 + i. MIKASA's wrapper table gives them no ``CurriculumPhaseNoopActionWrapper``: actions
act from the first step. The lamp's bulb is a mesh that MIKASA's wheel leaves out: ``lamp_asset`` puts the project's
copy of MIKASA's file in place before the env is made.

**Episode:** a blue cube (4 cm) rests on a green disc (7 cm radius), a red disc lies 22 cm to its left, and a white
lamp stands 22 cm beyond the pair. At step 1, 2 or 3 the lamp turns green and stays green. The robot must set the cube
on the red disc (its xy within 5 cm of the disc's centre, its centre lower than 6.6 cm) at step D of a count started
when the lamp turned green: D is 100, 150, 200 (Easy, Medium, Hard), 300, 500 or 1000 (the -Long), and MIKASA
accepts counts from int(0.95 D) to int(1.05 D). The cube on the red disc earlier fails the episode at once, as does
the window passing; MIKASA's env ends an episode at success or failure. Episodes last 200, 250, 300, 600, 900 or 1200
control steps.

**Randomisations** (MIKASA's): the step the lamp turns green (1-3, uniform); the discs' place (their midpoint at x
-0.15 to -0.05 m, y -0.05 to 0.05 m), the cube's and the lamp's with them; the arm's initial joints.

**Success:** MIKASA's: the cube on the red disc at a count in the window, never before it.

**Facts:** one, read from the base camera: the lamp's green bulb is emissive and renders at the full level of the
green channel with the other two dark (``read_lit_colour``; 46-52 pixels where measured), which nothing else in the
scene reaches. The writer sees it turn green at the env's own signal step (the observation after step k shows the
lamp as MIKASA's count sets it at step k), then writes, after every chunk, how many control steps ago that was:
``the lamp turned green 96 steps ago.``, the fact replaced in place as the count goes on. Once the lamp is green,
nothing in a frame tells the count: a memoryless controller has no clock, so the count reaches it only through its
prompt. Decoys are worded alike about other things with counts of their own (``the key turned green 40 steps
ago.``). A controller that kept its own count from the reset would need no memory (every signal step's window holds
counts 98-105 of the episode for D = 100): that is the memory this task asks the frozen controller's prompt to carry.

**The oracle and wrong conditions** carry the time too (``Task.facts_at``): the oracle states the true count at each
decision, the wrong one a count ``D // 2`` ahead of it (the expert sets the cube down half the delay too early).

**The expert** (``TimedTransferController``) carries the cube over the red disc and sets it down when its prompt's
count reaches D (from its instruction) less ``lead`` steps; without a count it holds the cube over the disc, a guess
that never succeeds. It reads the cube's and the discs' positions from a detector, as the other MIKASA experts do (a
simulated detector: a privileged upper bound).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import NUMBER, PromptTemplate
from sb3_memret.memory.schema import MemoryEntry, MemoryType
from sb3_memret.memory.seeding import SeedingConfig
from sb3_memret.tasks.base import EnvFrame, Episode, Predicates
from sb3_memret.tasks.mikasa.core import demo_layout
from sb3_memret.tasks.mikasa.core.cue_task import MikasaCueTask
from sb3_memret.tasks.mikasa.core.lamp_perception import read_lit_colour
from sb3_memret.tasks.mikasa.core.perception import DetectorObservation, stack_positions
from sb3_memret.tasks.mikasa.timed_transfer.expert import TimedTransferController

# MIKASA's language instruction in the prompt contract's form: lowercase, its two sentences joined by a semicolon (the
# contract reads a prompt's first sentence as the instruction), the delay a field
INSTRUCTION = ("when the white lamp turns green, start counting steps from that exact moment; move the blue cube from "
               "the green disc to the red disc exactly on step {delay} of that count.")
FACT_TEMPLATE = "the {entity} turned green {count} steps ago."
CUE_ENTITY = "lamp"
CUE_RELATION = "turned_green"  # OTHER's template, "the {entity} {relation} {value}.", reads FACT_TEMPLATE
CUE_FACT = "the lamp turned green {count} steps ago."
PROMPT_TEMPLATE = PromptTemplate(instructions=(INSTRUCTION,), fact_templates=(FACT_TEMPLATE,),
                                 fields=(("delay", NUMBER), ("count", NUMBER)))
# MIKASA's variants: the delay D (its DELAY_STEPS) and the episode's control steps (its registered max_episode_steps)
VARIANTS: dict[str, tuple[int, int]] = {
    "TimedTransferEasy-VLA-v0": (100, 200), "TimedTransferMedium-VLA-v0": (150, 250),
    "TimedTransferHard-VLA-v0": (200, 300), "TimedTransferEasy-Long-VLA-v0": (300, 600),
    "TimedTransferMedium-Long-VLA-v0": (500, 900), "TimedTransferHard-Long-VLA-v0": (1000, 1200),
}
SIGNAL_STEPS = (1, 3)  # MIKASA's PRE_SIGNAL_STEPS: the lamp turns green at one of these steps (inclusive)


def count_value(steps: int) -> str:
    """The fact's value for a count (``96 steps ago``): OTHER's template words it ``the lamp turned green 96 steps
    ago.``."""
    if steps < 0:
        raise ValueError(f"a count is a whole number of steps >= 0, got {steps}")
    return f"{steps} steps ago"


class SignalWriter:
    """Writes ``the lamp turned green 96 steps ago.`` after every frame from the one whose percept first showed the
    lamp green, counting control steps from that one (the reset frame, ``steps == 0``, starts an episode). Percepts
    are booleans: the lamp lit green in the step's base-camera frame. Never seen green, nothing written."""

    relations = {"signal": (MemoryType.OTHER, CUE_RELATION)}

    def __init__(self) -> None:
        self.t, self.signal = 0, None

    def read(self, frame: EnvFrame) -> list[tuple[int, Predicates]]:
        if frame.steps == 0:
            self.t, self.signal = 0, None
        for step, green in frame.timed_percepts():
            if green and self.signal is None:
                self.signal = self.t + step
        self.t += frame.steps
        if self.signal is None:
            return []
        return [(frame.steps, {("signal", CUE_ENTITY): count_value(self.t - self.signal)})]


@dataclass(frozen=True)
class SignalEpisode(Episode):
    """A TimedTransfer episode's ground truth: the lamp's fact is true when its count is the control steps from the
    env's signal step (``details["signal_step"]``) to the step it was written at; it changes at every step."""

    def is_true(self, entry: MemoryEntry) -> bool:
        signal = int(self.details["signal_step"])
        expected = count_value(entry.timestamp - signal) if entry.timestamp >= signal else None
        return entry.key == (MemoryType.OTHER, CUE_ENTITY, CUE_RELATION) and entry.value == expected


class TimedTransferObservation(DetectorObservation):
    """A TimedTransfer observation cut to a controller's view: the joints, the hand, the cameras, the discs
    (``extra/disc_positions`` (B, 2, 3): green, then red; ``extra/disc_visible``) and the cube's position
    (``extra/cube_position``, (B, 3)). The lamp, MIKASA's signal step and counters are not among them."""

    def __init__(self, env: gym.Env):
        super().__init__(env, lambda base: [base.green_disc, base.red_disc], "disc")
        batch = int(getattr(env.unwrapped, "num_envs", 1))
        self.observation_space["extra"]["cube_position"] = spaces.Box(-np.inf, np.inf, (batch, 3), np.float32)

    def observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out = super().observation(obs)
        out["extra"]["cube_position"] = stack_positions([self.env.unwrapped.blue_cube.pose.p],
                                                        like=obs["extra"]["tcp_pose"])[:, 0]
        return out


class TimedTransferTask(MikasaCueTask):
    """MIKASA-Robo-VLA's TimedTransfer{Easy,Medium,Hard}[-Long]-VLA-v0 (``VARIANTS``): set the cube on the red disc on
    the step the instruction names, counted from when the lamp turned green."""

    field, detector_key, truth_attribute = "count", "disc", "signal_step"
    cue_entity, cue_relation, cue_fact = CUE_ENTITY, CUE_RELATION, CUE_FACT
    instruction_text, template, vocabulary = INSTRUCTION, PROMPT_TEMPLATE, (CUE_ENTITY,)
    observation_wrapper: ClassVar = TimedTransferObservation
    noop_before_manipulation = False  # MIKASA's wrapper table gives TimedTransfer none
    group_name = "signal step"

    def __init__(self, env_id: str = "TimedTransferEasy-VLA-v0"):
        if env_id not in VARIANTS:
            raise ValueError(f"unknown TimedTransfer task {env_id!r}; expected one of {sorted(VARIANTS)}")
        super().__init__(env_id, 1)
        self.delay, self.max_control_steps = VARIANTS[env_id]

    # ------------------------------------------------------------ simulation
    def make_env(self, *, max_episode_steps: int | None = None, num_envs: int = 1, obs_mode: str = "rgb",
                 render_backend: str = "cpu", **kwargs: Any) -> gym.Env:
        from sb3_memret.tasks.mikasa.core.lamp_asset import install_lamp_asset

        install_lamp_asset()  # the lamp's bulb mesh, which MIKASA's wheel leaves out
        return super().make_env(max_episode_steps=max_episode_steps, num_envs=num_envs, obs_mode=obs_mode,
                                render_backend=render_backend, **kwargs)

    def frames(self, env: gym.Env, obs: Any, info: Mapping[str, Any], reset: bool = False) -> list[EnvFrame]:
        from sb3_memret.common.obs_trees import select_obs, to_numpy

        obs = to_numpy(obs)
        signal = as_numpy(env.unwrapped.signal_step).reshape(-1)  # privileged: for metrics only
        success = as_numpy(info["success"]).reshape(-1)
        return [EnvFrame(select_obs(obs, i), {"signal_step": int(signal[i])}, None, bool(success[i]))
                for i in range(len(success))]

    def perceive(self, env: gym.Env, obs: Any) -> bool:
        return read_lit_colour(as_numpy(obs["sensor_data"]["base_camera"]["rgb"])[0]) == "green"

    def perception_window(self, env: gym.Env) -> int | None:
        """The latest step the lamp can turn green (MIKASA's ``PRE_SIGNAL_STEPS``), and one more: after it the
        writer only counts."""
        return int(max(getattr(env.unwrapped, "PRE_SIGNAL_STEPS", SIGNAL_STEPS))) + 1

    # ------------------------------------------------------------ memory
    def writer(self, source: str = "seeded") -> SignalWriter:
        return SignalWriter()

    def episode(self, frame: EnvFrame) -> Episode:
        signal = int(frame.state["signal_step"])
        return SignalEpisode(self.cue_entity, f"step {signal}", ((self.cue_key, f"green at step {signal}"),),
                             {"signal_step": signal})

    def seed_memories(self, frame: EnvFrame, episode: Episode, rng: np.random.Generator, seeding: SeedingConfig,
                      facts: bool = True) -> list[MemoryEntry]:
        """``seeding.location_decoys`` facts worded as the lamp's about other things, each with a count up to the
        delay (``the key turned green 40 steps ago.``); the lamp's own fact comes only from what the camera saw."""
        vocab = sorted(set(seeding.vocabulary) - {CUE_ENTITY})
        return [MemoryEntry.create(MemoryType.OTHER, str(word), CUE_RELATION,
                                   count_value(int(rng.integers(0, self.delay + 1))), 0)
                for word in rng.choice(vocab, size=seeding.location_decoys, replace=False)]

    # ------------------------------------------------------------ prompts and controllers
    def instruction(self, episode: Episode) -> str:
        return INSTRUCTION.format(delay=self.delay)

    def oracle_facts(self, episode: Episode) -> list[str]:
        raise ValueError(f"{self.name}'s facts carry the time (how many steps ago the lamp turned green): ask "
                         "Task.facts_at(condition, episode, t) for them as they read t steps into the episode")

    def wrong_facts(self, episode: Episode) -> list[str]:
        return self.oracle_facts(episode)

    def facts_at(self, condition: str, episode: Episode, t: int) -> list[str]:
        """The oracle: the true count ``t`` steps in (none before the lamp turns green); wrong: ``delay // 2`` more."""
        if condition not in ("oracle", "wrong"):
            raise ValueError(f"condition {condition!r} has no facts of its own; expected 'oracle' or 'wrong'")
        count = t - int(episode.details["signal_step"])
        if count < 0:
            return []
        return [CUE_FACT.format(count=count + (self.delay // 2 if condition == "wrong" else 0))]

    def expert(self) -> TimedTransferController:
        """The timed carry expert; without a count it holds the cube over the red disc (never succeeds)."""
        return TimedTransferController(PROMPT_TEMPLATE)

    def demo_features(self, with_images: bool) -> dict[str, dict[str, Any]]:
        return demo_layout.with_state_extra(demo_layout.demo_features(("green", "red"), with_images, key="disc"),
                                            "cube")

    def demo_frame(self, obs: Obs, with_images: bool) -> dict[str, np.ndarray]:
        return demo_layout.append_state(demo_layout.demo_frame(obs, with_images, key="disc"),
                                        obs["extra"]["cube_position"])


__all__ = ["CUE_FACT", "FACT_TEMPLATE", "INSTRUCTION", "PROMPT_TEMPLATE", "SIGNAL_STEPS", "SignalEpisode",
           "SignalWriter", "TimedTransferObservation", "TimedTransferTask", "VARIANTS", "count_value"]

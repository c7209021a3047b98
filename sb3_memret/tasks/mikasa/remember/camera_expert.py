"""RememberColor's touch expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper bound.

``ScriptedTouchController`` reads a simulated detector (every cube's pose from the simulator) and the arm's joint
velocities, so its rows are a privileged upper bound. ``CameraTouchController`` is the same motion on the harness's
inputs only (``ControllerSpec.harness_inputs``):

- **where the cubes stand**: read from the base camera's image with its shipped calibration (``CubeLayout``: each
  colour's first sighting in a frame that shows more than the cue's one cube, cast onto the table). At RememberColor9's
  development seeds 5000-5009 all nine cubes were placed at every seed, 0.03-0.52 cm from the simulator's, once
  touching cubes were split by colour (``name_blobs``); before, two to four of the nine went unplaced at 4 of the
  first 5 seeds;
- **the hand's motion**: dead-reckoned from the hand's pose and the actions that ran (``DeadReckonedHand``, at the
  pace it declares, ``paced_every``; every runner refuses another).

Like the detector's version it heads for the cube its prompt's fact names (without one, the first colour: a guess),
and where no wrapper freezes the arm through the cue and the delay (the -Long variants) it waits at its ready pose
until every cube is placed. It keeps per-env perception (the layout, the hand's last position and step;
``reset``/``reset_envs`` clear it), never the cue: that reaches it through its prompt alone.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.hand_motion import DeadReckonedHand
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, CubeLayout
from sb3_memret.tasks.mikasa.core.touch_expert import ScriptedTouchController, TouchGains


class CameraTouchController(ScriptedTouchController):
    """Touches the cube of the colour its prompt names, reading only the base camera's image and the hand's pose (the
    module docstring says how). ``colours``: the cubes in play (MIKASA's order); ``paced_every``: the control steps
    executed between its calls; ``read_layout``: one image -> colour -> table (x, y) (the base camera's reader by
    default)."""

    def __init__(self, colours: Sequence[str], prompt_template: PromptTemplate, paced_every: int,
                 chunk_len: int = 8, gains: TouchGains | None = None, default: str | None = None,
                 wait_for_all: bool = False, read_layout: Callable[[Any], Mapping[str, np.ndarray]] | None = None):
        super().__init__(chunk_len, gains, vocabulary=colours, field="colour", prompt_template=prompt_template,
                         default=default, wait_for_all=wait_for_all)
        self.hand = DeadReckonedHand(paced_every, chunk_len)
        self.spec = dataclasses.replace(self.spec, needs_images=True, harness_inputs=True)
        self.stateful = True  # its perception: the layout, the hand's last position and step (never the cue)
        self.paced_every, self.read_layout = paced_every, read_layout
        self.layouts: list[CubeLayout] = []

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.layouts = [CubeLayout(1, len(self.vocabulary), self.read_layout) for _ in seeds]
        self.hand.reset(len(seeds))

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        super().reset_envs(env_ids, seeds)
        for i in env_ids:
            self.layouts[i].reset()
            self.hand.reset_env(i)

    def reads_images(self) -> bool:
        """Until every env's layout is complete: the cubes stand still once out, and nothing else is read."""
        return not self.layouts or not all(layout.complete for layout in self.layouts)

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(prompts) != self._batch:
            raise RuntimeError(f"reset() was called for {self._batch} envs but act() got {len(prompts)} prompts")
        tcp = as_numpy(obs["extra"]["tcp_pose"]).astype(np.float64)
        steps = self.hand.steps(tcp[:, :3])
        rgb = obs["sensor_data"]["base_camera"]["rgb"]
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, word in enumerate(self._chosen(parsed)):
            layout = self.layouts[i]
            layout.see(rgb[i])
            if word is None:
                continue  # no cue fact (or a word it was never trained on) and no default: hold still
            place = layout.places.get(word)
            choosing = not self.wait_for_all or layout.complete
            target = np.array([*place, LAYOUT_PLANE_Z]) if place is not None and choosing else None
            chunks[i] = self._chunk(tcp[i], steps[i], target)
        self.hand.ran(tcp[:, :3], steps, chunks)
        return chunks


__all__ = ["CameraTouchController"]

"""The colour-cue tasks' expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper bound.

``SequenceTouchController`` reads a simulated detector (every cube's pose from the simulator) and the arm's joint
velocities, so its rows are a privileged upper bound. ``CameraSequenceController`` is the same motion and plan on the
harness's inputs only (``ControllerSpec.harness_inputs``):

- **where the cubes stand**: read from the base camera's image with its shipped calibration (``CubeLayout``: each
  colour's first sighting once the cubes are out, cast onto the table; 0.55 cm from the simulator's on SeqOfColors3),
  a colour not yet placed counting as out of sight (so it waits at its ready pose through the cue and the delay, as
  the detector's version does);
- **the button**: MIKASA stands it at the cubes' mean, 4 cm toward the robot (``button_place``, as the writer places
  it);
- **the hand's motion**: where the detector's version reads the joints' velocities, this one dead-reckons the TCP's
  step from the hand's pose and the actions that ran (``DeadReckonedHand``; it is run at the pace it declares,
  ``paced_every``, and every runner refuses another).

What has been done comes from its prompt's progress facts only (``progress_from="prompt"``): a touch or a press
cannot be told from the hand's pose without the joints' speeds, so this controller is the stateless expert's, fed
by the writer (written, recall) or MIKASA's counters (oracle). It keeps per-env perception (the layout, the hand's
last position and step, the translations that ran; ``reset``/``reset_envs`` clear it), never the cue: that reaches it
through its prompt alone.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import PromptTemplate
from sb3_memret.tasks.mikasa.core.hand_motion import DeadReckonedHand
from sb3_memret.tasks.mikasa.core.layout_perception import LAYOUT_PLANE_Z, CubeLayout
from sb3_memret.tasks.mikasa.core.perception import COLOUR_NAMES
from sb3_memret.tasks.mikasa.core.sequence_expert import SequenceGains, SequenceTouchController
from sb3_memret.tasks.mikasa.core.touch_expert import TouchGains
from sb3_memret.tasks.mikasa.seq_of_colors.writer import N_COLOURS, button_place


class CameraSequenceController(SequenceTouchController):
    """Touches the prompt's colours in order and presses the button, reading only the base camera's image and the
    hand's pose (the module docstring says how). ``shown_at_once``: the most cubes the task's cue shows at once (1
    for a sequence, the bunch's size for a bunch); ``paced_every``: the control steps executed between its calls
    (``pacing.replan_interval`` refuses any other); ``read_layout``: one image -> colour -> table (x, y) (the base
    camera's reader by default)."""

    def __init__(self, prompt_template: PromptTemplate, shown_at_once: int, paced_every: int, chunk_len: int = 8,
                 gains: TouchGains | None = None, sequence_gains: SequenceGains | None = None,
                 read_layout: Callable[[Any], Mapping[str, np.ndarray]] | None = None):
        super().__init__(prompt_template, chunk_len, gains, sequence_gains, COLOUR_NAMES[:N_COLOURS],
                         progress_from="prompt")
        self.hand = DeadReckonedHand(paced_every, chunk_len)
        self.spec = dataclasses.replace(self.spec, needs_images=True, harness_inputs=True)
        self.stateful = True  # its perception: the layout, the hand's last position and step (never the cue)
        self.shown_at_once, self.paced_every, self.read_layout = shown_at_once, paced_every, read_layout
        self.layouts: list[CubeLayout] = []
        self._steps = np.zeros((0, 3))

    def reset(self, seeds: Sequence[int]) -> None:
        super().reset(seeds)
        self.layouts = [CubeLayout(self.shown_at_once, N_COLOURS, self.read_layout) for _ in seeds]
        self.hand.reset(len(seeds))

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        super().reset_envs(env_ids, seeds)
        for i in env_ids:
            self.layouts[i].reset()
            self.hand.reset_env(i)

    def reads_images(self) -> bool:
        """Until every env's layout is complete: the cubes stand still once out, and nothing else is read."""
        return not self.layouts or not all(layout.complete for layout in self.layouts)

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[Any]) -> np.ndarray:
        tcp = as_numpy(obs["extra"]["tcp_pose"]).astype(np.float64)[:, :3]
        self._steps = self.hand.steps(tcp)
        chunks = super()._act(obs, prompts, parsed)
        self.hand.ran(tcp, self._steps, chunks)
        return chunks

    def _detections(self, obs: Obs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The cubes the base camera has placed (at the height their seen pixels were cast to) and the button
        placed from them; a colour not yet placed is out of sight."""
        rgb = obs["sensor_data"]["base_camera"]["rgb"]
        cubes = np.zeros((self._batch, N_COLOURS, 3))
        visible = np.zeros((self._batch, N_COLOURS), dtype=bool)
        button = np.zeros((self._batch, 3))
        for i, layout in enumerate(self.layouts):
            layout.see(rgb[i])
            for colour, (x, y) in layout.places.items():
                index = self.vocabulary.index(colour)
                cubes[i, index], visible[i, index] = (x, y, LAYOUT_PLANE_Z), True
            if layout.complete:
                button[i] = button_place(layout.places)
        return cubes, visible, button

    def _motion(self, obs: Obs, tcp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The TCP's step now (``DeadReckonedHand``, estimated as this call began), and whether it is under the writer's
        ``still_step``."""
        return self._steps, np.linalg.norm(self._steps, axis=1) <= self.seq.still_step


__all__ = ["CameraSequenceController"]

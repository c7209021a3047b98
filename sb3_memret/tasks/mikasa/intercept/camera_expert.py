"""Intercept's catching expert on what MIKASA's harness gives a policy alone: a protocol entry, not an upper bound.

``InterceptController`` reads the ball's and the target's positions from a simulated detector (the ball whenever
its centre is inside the base camera's image, the hand over it or not) and the arm's joint velocities, so its rows
are a privileged upper bound. ``CameraInterceptController`` is the same plan and motion on the harness's inputs only
(``ControllerSpec.harness_inputs``):

- **the ball**: its pixels in the base camera at every call, cast onto the plane of its centre through the shipped
  calibration (``ball_on_table``, the writer's reader). Where a frame does not show it whole (the fingers round it,
  the image's edge) after it was seen, it is where its last sighting and the prompt's velocity put it now: the
  detector's version predicts it so within a chunk already;
- **the ball in hand**: once the fingers' gap closes on it with the TCP at the ball, it goes where the hand goes,
  seen or not, until the gap opens (``HeldBall``);
- **the target** (Intercept): its red rings in the first frame that shows them (``read_target``, cast onto the
  table; 0.6-1.1 cm from its centre at development seeds 5000-5009, inside its 10 cm radius);
- **the hand's motion**: dead-reckoned from the hand's pose and the actions that ran (``DeadReckonedHand``).

The ball's velocity comes from its prompt alone, as for the detector's version.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from sb3_memret.controllers.base import Obs, as_numpy
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate
from sb3_memret.tasks.mikasa.core.calibration import BASE_CAMERA_EXTRINSIC, BASE_CAMERA_INTRINSIC
from sb3_memret.tasks.mikasa.core.harness_expert import HarnessExpert
from sb3_memret.tasks.mikasa.core.layout_perception import table_points
from sb3_memret.tasks.mikasa.core.perception import REFERENCE_SIZE
from sb3_memret.tasks.mikasa.core.touch_expert import CONTROL_DT
from sb3_memret.tasks.mikasa.intercept.expert import GRIP_OPEN, CatchGains, InterceptController
from sb3_memret.tasks.mikasa.intercept.task import BALL_CENTRE_Z, ball_on_table

TARGET_Z = 0.001  # the target's height
MIN_TARGET_PIXELS = 60  # at 128x128 its red rings show 110-220 pixels


def read_ball(rgb: Any) -> np.ndarray | None:
    """The ball's table (x, y) in one base-camera frame through the shipped calibration; None unless seen whole."""
    return ball_on_table(np.asarray(as_numpy(rgb)), BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC)


def read_target(rgb: Any) -> np.ndarray | None:
    """The target's table (x, y) from one base-camera frame: its red rings (about (200, 70, 70): green and blue
    alike, where the wood's green is well above its blue and the ball's are both near 0), cast onto the table; None
    with too few of them in sight."""
    frame = np.asarray(as_numpy(rgb)).astype(np.int16)
    red, green, blue = frame[..., 0], frame[..., 1], frame[..., 2]
    mask = (red >= 150) & (green >= 30) & (green <= 100) & (np.abs(green - blue) <= 20)
    if mask.sum() < MIN_TARGET_PIXELS * np.prod(np.array(mask.shape) / REFERENCE_SIZE):
        return None
    points = table_points(np.argwhere(mask) + 0.5, BASE_CAMERA_INTRINSIC, BASE_CAMERA_EXTRINSIC, TARGET_Z)
    centre = points.mean(axis=0)
    return centre if np.isfinite(centre).all() else None


class HeldBall:
    """Each env's ball as far as it knows: its last sighting (x, y) and the control steps since, and whether it is in
    hand (then it is wherever the TCP is)."""

    def __init__(self, gains: CatchGains):
        self.gains = gains
        self.seen: list[np.ndarray | None] = []
        self.since: list[int] = []
        self.held: list[bool] = []

    def reset(self, n_envs: int) -> None:
        self.seen, self.since, self.held = [None] * n_envs, [0] * n_envs, [False] * n_envs

    def reset_env(self, i: int) -> None:
        self.seen[i], self.since[i], self.held[i] = None, 0, False

    def see(self, i: int, place: np.ndarray | None) -> None:
        """Record a frame's reading of env ``i``'s ball (None: not seen whole)."""
        if place is not None:
            self.seen[i], self.since[i] = np.asarray(place, dtype=np.float64), 0

    def where(self, i: int, tcp: np.ndarray, gap: float, velocity: np.ndarray) -> np.ndarray | None:
        """Env ``i``'s ball (x, y, z) now, the TCP at ``tcp`` with the fingers ``gap`` apart: in hand, at the TCP;
        else its last sighting moved on at ``velocity`` (m/s) for the steps since; None if never seen."""
        g = self.gains
        if self.seen[i] is None:
            return None
        ball = np.array([*(self.seen[i] + np.asarray(velocity) * CONTROL_DT * self.since[i]), BALL_CENTRE_Z])
        closed = g.held_gap[0] <= gap <= g.held_gap[1]
        self.held[i] = closed and (self.held[i] or np.linalg.norm(ball - tcp) <= g.held_reach)
        return np.asarray(tcp, dtype=np.float64).copy() if self.held[i] else ball

    def ran(self, steps: int) -> None:
        """``steps`` control steps ran since the last call."""
        self.since = [since + steps for since in self.since]


class CameraInterceptController(HarnessExpert, InterceptController):
    """Catches the ball at the velocity its prompt states and, for Intercept, carries it onto the target, reading
    only the base camera's image, the hand's pose and the gripper's opening (the module docstring says how).
    ``paced_every``: the control steps executed between its calls; ``read_ball`` and ``read_target``: image -> a
    table (x, y) or None (the base camera's readers by default)."""

    def __init__(self, prompt_template: PromptTemplate, default_speed: float, carry: bool, paced_every: int,
                 chunk_len: int = 8, gains: CatchGains | None = None,
                 read_ball: Callable[[Any], np.ndarray | None] = read_ball,
                 read_target: Callable[[Any], np.ndarray | None] = read_target):
        super().__init__(prompt_template, default_speed, carry, chunk_len, gains)
        self._on_harness(paced_every, chunk_len)
        self.read_ball, self.read_target = read_ball, read_target
        self.ball = HeldBall(self.gains)
        self.targets: list[np.ndarray | None] = []

    def _forget(self, n_envs: int) -> None:
        self.ball.reset(n_envs)
        self.targets = [None] * n_envs

    def _forget_env(self, i: int) -> None:
        self.ball.reset_env(i)
        self.targets[i] = None

    def reads_images(self) -> bool:
        """Always: the ball rolls until it is caught."""
        return True

    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        g = self.gains
        inputs = self._harness_inputs(obs, len(prompts))
        tcp, gaps, steps, rgb = inputs
        chunks = np.zeros((len(prompts), self.spec.chunk_len, self.spec.action_dim))
        for i, p in enumerate(parsed):
            self.ball.see(i, self.read_ball(rgb[i]))
            if self.carry and self.targets[i] is None:
                self.targets[i] = self.read_target(rgb[i])
            velocity = self.motion_of(p).velocity
            ball = self.ball.where(i, tcp[i, :3], float(gaps[i]), velocity)
            if ball is None:
                chunks[i] = self._hold(tcp[i], steps[i], np.asarray(g.ready), grip=GRIP_OPEN)
            elif self.ball.held[i]:
                target = self.targets[i]
                point = tcp[i, :3] if not self.carry or target is None else np.array([*target, g.carry_height])
                chunks[i] = self._hold(tcp[i], steps[i], point)
            else:
                chunks[i] = self._catch(tcp[i], steps[i], ball, velocity)
        self.ball.ran(self.paced_every)
        return self._ran(inputs, chunks)


__all__ = ["CameraInterceptController", "HeldBall", "read_ball", "read_target"]

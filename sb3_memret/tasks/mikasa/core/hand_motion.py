"""The hand's motion from its pose alone, for experts on the harness's inputs (no joint velocities).

Where the detector-fed experts read the TCP's velocity from the arm's joints (``touch_expert.tcp_velocity``), MIKASA's
harness gives a policy only the hand's pose. ``DeadReckonedHand`` estimates each env's TCP step (metres per control
step) with the arm model the experts' chunks are planned with (``touch_expert``: each step ``DRIVE_GAIN * POS_SCALE
* delta + COAST_GAIN * the last step``), run over the translations of the last chunk that were executed
(``paced_every`` of them), and corrects it by what the model missed of the hand's measured displacement, spread
evenly over those steps. The displacement's plain mean lags a moving hand: on SeqOfColors3 (development seed 5000)
chunks planned on it braked late and overshot a cube by 2 cm.
"""

from __future__ import annotations

import numpy as np

from sb3_memret.tasks.mikasa.core.touch_expert import COAST_GAIN, DRIVE_GAIN, POS_SCALE


class DeadReckonedHand:
    """Each env's TCP step, estimated at each call from the hand's position and the chunk the last call sent.
    ``paced_every``: the control steps executed between calls (every runner executes that many: see
    ``pacing.replan_interval``, which refuses another interval for a controller that declares it)."""

    def __init__(self, paced_every: int, chunk_len: int):
        if not 1 <= paced_every <= chunk_len:
            raise ValueError(f"paced_every must be in 1..{chunk_len} (the chunk's length), got {paced_every}")
        self.paced_every = paced_every
        # per env, from its last call: the TCP's position and estimated step, and the translations that then ran
        self.sent: list[tuple[np.ndarray, np.ndarray, np.ndarray] | None] = []

    def reset(self, n_envs: int) -> None:
        self.sent = [None] * n_envs

    def reset_env(self, i: int) -> None:
        self.sent[i] = None

    def steps(self, tcp: np.ndarray) -> np.ndarray:
        """(B, 3) TCP steps now, from the (B, 3) TCP positions of this call (zero at an episode's first call)."""
        tcp = np.asarray(tcp, dtype=np.float64).reshape(-1, 3)
        return np.array([self.step_now(i, tcp[i]) for i in range(len(tcp))]).reshape(-1, 3)

    def step_now(self, i: int, tcp: np.ndarray) -> np.ndarray:
        """Env ``i``'s TCP step now: the arm model run over the translations that ran since its last call, from the
        step estimated then, plus the model's miss of the measured displacement spread over those steps."""
        if self.sent[i] is None:
            return np.zeros(3)
        before, step, actions = self.sent[i]
        predicted = np.zeros(3)
        for action in actions:
            step = DRIVE_GAIN * POS_SCALE * action + COAST_GAIN * step
            predicted += step
        return step + (tcp - before - predicted) / len(actions)

    def ran(self, tcp: np.ndarray, steps: np.ndarray, chunks: np.ndarray) -> None:
        """Record this call: the (B, 3) TCP positions and ``steps`` estimated, and the translations of the (B, H, 7)
        ``chunks`` sent that will run before the next call."""
        tcp = np.asarray(tcp, dtype=np.float64).reshape(-1, 3)
        self.sent = [(tcp[i], np.asarray(steps[i], dtype=np.float64),
                      np.asarray(chunks[i, : self.paced_every, :3], dtype=np.float64)) for i in range(len(tcp))]


__all__ = ["DeadReckonedHand"]

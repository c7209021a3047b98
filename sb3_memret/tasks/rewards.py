"""The bank-blind staged potential and its shaping reward, and the value of an absorbing success.

Computed from cube, end-effector and drawer geometry only, so it can never tell which
memory was retrieved. Stages: reaching 1 - tanh(d / 0.2) in [0, 1]; grasped 2 + reach;
clear of every drawer 4 + reach; success (taken out) exactly 6.
"""

from __future__ import annotations

import numpy as np

PHI_MAX = 6.0
REACH_SCALE = 0.2


def staged_potential(
    eef_pos: np.ndarray,
    target_pos: np.ndarray,
    grasped: np.ndarray,
    clear: np.ndarray,
    success: np.ndarray,
) -> np.ndarray:
    """Φ(s) for a batch: positions (B, 3), flags (B,). Monotone in task progress."""
    reach = 1.0 - np.tanh(np.linalg.norm(np.asarray(eef_pos) - np.asarray(target_pos), axis=-1) / REACH_SCALE)
    phi = reach + 2.0 * np.asarray(grasped, dtype=bool)
    phi = np.where(np.asarray(clear, dtype=bool), reach + 4.0, phi)
    return np.where(np.asarray(success, dtype=bool), PHI_MAX, phi)


def shaped_reward(phi: np.ndarray, phi_next: np.ndarray, gamma: float) -> np.ndarray:
    """Potential-based shaping r = γΦ(s') − Φ(s) (Ng et al., 1999)."""
    if not 0.0 < gamma <= 1.0:
        raise ValueError(f"gamma must be in (0, 1], got {gamma!r}")
    return gamma * np.asarray(phi_next) - np.asarray(phi)


def absorbing_success_value(reward: float, remaining_steps: int, steps_left_in_decision: int,
                            steps_per_decision: int, gamma: float) -> float:
    """What an episode cut short at its success forgoes, in decision rewards: ``reward`` at each of the
    ``remaining_steps`` control steps it would still have run, (1 - gamma)-scaled as a decision's reward is,
    undiscounted for the steps its current decision had left and discounted by gamma per later decision.

    Ending at success saves simulation, but without this an early success would pay less than failing
    slowly while the env's dense terms run on (the success state is absorbing in the env it stands for).
    """
    if not 0.0 < gamma <= 1.0:
        raise ValueError(f"gamma must be in (0, 1], got {gamma!r}")
    if steps_per_decision < 1 or remaining_steps < 0 or steps_left_in_decision < 0:
        raise ValueError(f"step counts must be non-negative (and steps_per_decision >= 1), got remaining_steps="
                         f"{remaining_steps}, steps_left_in_decision={steps_left_in_decision}, "
                         f"steps_per_decision={steps_per_decision}")
    now = min(remaining_steps, steps_left_in_decision)
    later, partial = divmod(remaining_steps - now, steps_per_decision)
    discounted = steps_per_decision * sum(gamma ** j for j in range(1, later + 1)) + partial * gamma ** (later + 1)
    return (1.0 - gamma) * reward * (now + discounted)

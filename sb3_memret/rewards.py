"""The bank-blind staged potential and its shaping reward.

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

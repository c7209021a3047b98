"""A lit lamp in one camera frame: MIKASA's lamps light an emissive bulb (``build_color_switch_lamp``), which renders
at the full level of its colour's channel (255, the other two <= 3); nothing else in MIKASA's scenes reaches it (a red
cube's faces render at 231 and 148, the green disc at <= 244 with red and blue at 30). GatherAndRecall reads its
flash's colour here, TimedTransfer the moment its lamp turns green.
"""

from __future__ import annotations

import numpy as np

LAMP_COLOURS: tuple[str, ...] = ("red", "green", "blue")  # a lit pixel's brightest channel, in RGB order
LIT_LEVEL = 250  # the lit bulb's channel renders at 255
DARK_LEVEL = 30  # ... and its other two at most 3
MIN_LIT_PIXELS = 8  # at 128x128: a lit bulb covered 85-110 pixels in GatherAndRecall, 46-52 in TimedTransfer
MIN_VOTE_SHARE = 0.8  # lit pixels that disagree more than this are not read


def read_lit_colour(rgb: np.ndarray) -> str | None:
    """The colour of the lit bulb in one frame (H, W, 3) uint8, or None while no bulb is lit: the colour of the
    pixels lit to the full level of one channel with the other two dark (``LAMP_COLOURS``)."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise ValueError(f"expected one (H, W, 3) frame, got shape {rgb.shape}")
    pixels = rgb.reshape(-1, 3).astype(np.int16)
    channel = pixels.argmax(axis=1)
    others = np.sort(pixels, axis=1)[:, 1]  # the brighter of the other two
    lit = (pixels.max(axis=1) >= LIT_LEVEL) & (others <= DARK_LEVEL)
    scale = rgb.shape[0] * rgb.shape[1] / 128 ** 2
    if lit.sum() < MIN_LIT_PIXELS * scale:
        return None
    votes = np.bincount(channel[lit], minlength=3)
    best = int(votes.argmax())
    return LAMP_COLOURS[best] if votes[best] >= MIN_VOTE_SHARE * votes.sum() else None


__all__ = ["LAMP_COLOURS", "read_lit_colour"]

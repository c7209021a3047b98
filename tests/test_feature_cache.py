"""The trunk-feature cache: features computed once per dataset and read back exactly, recomputed only for frames
or a trunk it has not seen, and a cache that cannot be written warned about without losing the features."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sb3_memret.common.cache import CACHE_ENV, cache_root
from sb3_memret.stage1.feature_cache import FOLDER, cached_features, trunk_id


class MeanTrunk(torch.nn.Module):
    """A stand-in frozen trunk: each frame's channel means, counting the frames it was asked for."""

    def __init__(self, sha256: str = "ab" * 32):
        super().__init__()
        self.sha256, self.frames_seen = sha256, 0

    def compute(self, frames: np.ndarray) -> torch.Tensor:
        self.frames_seen += len(frames)
        return torch.from_numpy(frames.astype(np.float32).mean(axis=(1, 2))).half()


def frames(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(n, 8, 8, 3), dtype=np.uint8)


def test_features_are_computed_once_per_dataset_and_read_back_exactly(tmp_path):
    trunk, images = MeanTrunk(), np.concatenate([frames(5, 0), frames(3, 1)])
    first = cached_features(trunk, images, (5, 3), trunk.compute, root=tmp_path)
    assert first.shape == (8, 3) and trunk.frames_seen == 8
    assert len(list((tmp_path / FOLDER / trunk_id(trunk)).glob("*.npy"))) == 2
    again = cached_features(trunk, images, (5, 3), trunk.compute, root=tmp_path)
    assert trunk.frames_seen == 8 and torch.equal(again, first)
    # the second dataset alone, or after a new one (another concatenation): only the new frames are computed
    alone = cached_features(trunk, images[5:], (3,), trunk.compute, root=tmp_path)
    assert trunk.frames_seen == 8 and torch.equal(alone, first[5:])
    mixed = cached_features(trunk, np.concatenate([frames(2, 7), images[5:]]), (2, 3), trunk.compute, root=tmp_path)
    assert trunk.frames_seen == 10 and torch.equal(mixed[2:], first[5:])


def test_changed_frames_or_another_trunk_are_computed_afresh(tmp_path):
    trunk, images = MeanTrunk(), frames(4, 0)
    cached_features(trunk, images, (4,), trunk.compute, root=tmp_path)
    edited = images.copy()
    edited[2, 0, 0, 0] ^= 1  # one pixel
    cached_features(trunk, edited, (4,), trunk.compute, root=tmp_path)
    assert trunk.frames_seen == 8
    other = MeanTrunk("cd" * 32)
    cached_features(other, images, (4,), other.compute, root=tmp_path)
    assert other.frames_seen == 4 and trunk_id(other) != trunk_id(trunk)


def test_a_cached_file_of_another_shape_is_made_afresh(tmp_path):
    """A trunk cut at another depth keeps its weights' checksum but not its channel count: its features are remade."""
    trunk, images = MeanTrunk(), frames(4, 0)
    cached_features(trunk, images, (4,), trunk.compute, root=tmp_path)
    trunk.out_channels = 3
    cached_features(trunk, images, (4,), trunk.compute, root=tmp_path)
    assert trunk.frames_seen == 4
    trunk.out_channels = 5
    features = cached_features(trunk, images, (4,), trunk.compute, root=tmp_path)
    assert trunk.frames_seen == 8 and features.shape == (4, 3)


def test_bad_spans_and_a_trunk_without_a_checksum_are_refused(tmp_path):
    trunk = MeanTrunk()
    with pytest.raises(ValueError, match=r"spans \[2, 2\] cover 4 frames, not the 5 given"):
        cached_features(trunk, frames(5, 0), (2, 2), trunk.compute, root=tmp_path)
    with pytest.raises(ValueError, match="Linear has no weights checksum"):
        trunk_id(torch.nn.Linear(1, 1))


def test_an_unwritable_cache_is_warned_about_and_the_features_still_returned(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")  # a folder inside a file cannot be made
    trunk, images = MeanTrunk(), frames(3, 0)
    with pytest.warns(UserWarning, match=f"trunk features not cached: {blocker}.*{CACHE_ENV}"):
        features = cached_features(trunk, images, (3,), trunk.compute, root=blocker)
    assert torch.equal(features, trunk.compute(images))


def test_the_cache_root_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    assert cache_root() == tmp_path
    monkeypatch.delenv(CACHE_ENV)
    assert cache_root().name == "sb3-memret"

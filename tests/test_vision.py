"""Camera encoders: keypoints land where a feature map peaks, shifts move pixels without inventing any, and a
frozen trunk never trains."""

from __future__ import annotations

import pytest
import torch

from sb3_memret.controllers.learned.vision import EfficientNetLite0Trunk, SpatialSoftmax, make_camera_encoder, shift_augment


def test_spatial_softmax_finds_a_peak():
    maps = torch.full((1, 2, 9, 9), -50.0)
    maps[0, 0, 0, 8] = 50.0  # top right
    maps[0, 1, 8, 4] = 50.0  # bottom centre
    xy = SpatialSoftmax()(maps)
    torch.testing.assert_close(xy, torch.tensor([[1.0, 0.0, -1.0, 1.0]]), atol=1e-4, rtol=0)


def test_shifts_keep_shape_and_only_move_pixels():
    images = torch.arange(2 * 3 * 8 * 8, dtype=torch.float32).view(2, 3, 8, 8)
    shifted = shift_augment(images, 2, torch.Generator().manual_seed(0))
    assert shifted.shape == images.shape
    for b in range(2):
        values = set(images[b].flatten().tolist())
        assert set(shifted[b].flatten().tolist()) <= values  # edge padding repeats pixels, never blends them
    assert shift_augment(images, 0) is images


def test_heads_map_images_or_features_to_vectors():
    trunk, head = make_camera_encoder("cnn", 24)
    assert trunk is None and head(torch.rand(3, 3, 64, 64)).shape == (3, 24)
    trunk, head = make_camera_encoder("efficientnet_lite0", 24)
    features = trunk(torch.rand(3, 3, 128, 128))
    assert features.shape == (3, 40, 16, 16) and head(features).shape == (3, 24)
    _, wide = make_camera_encoder("efficientnet_lite0", 24, keypoints=48)  # more objects to locate: more keypoints
    assert wide.net[-1].out_channels == 48 and wide(features).shape == (3, 24)


def test_the_pretrained_trunk_is_frozen():
    trunk = EfficientNetLite0Trunk()
    trunk.train()
    assert not trunk.training and not any(p.requires_grad for p in trunk.parameters())
    x = torch.rand(2, 3, 64, 64)
    torch.testing.assert_close(trunk(x), trunk(x))  # batch-norm statistics never move


def test_a_colour_trunk_adds_the_image_averaged_to_its_grid():
    trunk, head = make_camera_encoder("efficientnet_lite0", 24, colour=True)
    images = torch.zeros(2, 3, 128, 128)
    images[0, 0, :8, :8] = 1.0  # a red patch filling the top-left cell of the 16 x 16 grid
    images[1, 2, 64:, 64:] = 0.5  # a dim blue bottom-right quarter
    features = trunk(images)
    assert features.shape == (2, 43, 16, 16) and head(features).shape == (2, 24)
    torch.testing.assert_close(features[:, :40], EfficientNetLite0Trunk()(images))  # the trunk's own maps, unchanged
    assert features[0, 40, 0, 0] == 1.0 and features[0, 40, 0, 1] == 0.0 and features[0, 41:].abs().max() == 0.0
    assert features[1, 42, 8:, 8:].eq(0.5).all() and features[1, 42, :8].abs().max() == 0.0
    trunk.train()
    assert not trunk.training and not any(p.requires_grad for p in trunk.parameters())


def test_colour_needs_a_frozen_trunk():
    with pytest.raises(ValueError, match="image_colour needs a frozen trunk"):
        make_camera_encoder("cnn", 24, colour=True)

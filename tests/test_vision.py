"""Camera encoders: keypoints land where a feature map peaks, shifts move pixels without inventing any, a
frozen trunk never trains, and a prompt-conditioned head finds the object its prompt names."""

from __future__ import annotations

import pytest
import torch

from sb3_memret.controllers.learned.vision import CameraHead, EfficientNetLite0Trunk, SpatialSoftmax, make_camera_encoder, shift_augment
from sb3_memret.stage1.feature_cache import trunk_id


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
    _, deep = make_camera_encoder("efficientnet_lite0", 24, trunk_head=((16, 3), (24, 1)))  # two convs, then keypoints
    convs = [layer for layer in deep.net if isinstance(layer, torch.nn.Conv2d)]
    assert [(c.in_channels, c.out_channels, c.kernel_size) for c in convs] == [(40, 16, (3, 3)), (16, 24, (1, 1)),
                                                                                (24, 32, (1, 1))]
    assert deep(features).shape == (3, 24)


def test_a_trunk_cut_at_stride_4_gives_finer_maps_cached_apart():
    """Cut at stride 4 the trunk gives 24 maps at 1/4 of the picture's side (objects of a few pixels get a cell or
    two each); its features are other features, so the cache names them apart."""
    fine, head = make_camera_encoder("efficientnet_lite0", 24, trunk_stride=4)
    features = fine(torch.rand(3, 3, 128, 128))
    assert features.shape == (3, 24, 32, 32) and head(features).shape == (3, 24)
    assert head.net[0].in_channels == 24
    coarse, _ = make_camera_encoder("efficientnet_lite0", 24)
    assert trunk_id(coarse) == f"EfficientNetLite0Trunk-{coarse.sha256[:16]}"  # features cached before the option
    assert trunk_id(fine) != trunk_id(coarse)
    coloured, _ = make_camera_encoder("efficientnet_lite0", 24, colour=True, trunk_stride=4)
    assert coloured(torch.rand(1, 3, 64, 64)).shape == (1, 27, 16, 16)
    assert len({trunk_id(coloured), trunk_id(fine), trunk_id(coarse)}) == 3


def test_a_trunk_fed_the_picture_enlarged_gives_finer_maps_cached_apart():
    """Enlarged 2x before the trunk, a 64-px picture gives the full trunk's 40 maps at 16x16, not 8x8; the
    features are those of the enlarged picture, cached under a name of their own."""
    enlarged, head = make_camera_encoder("efficientnet_lite0", 24, trunk_scale=2)
    coarse, _ = make_camera_encoder("efficientnet_lite0", 24)
    images = torch.rand(2, 3, 64, 64)
    features = enlarged(images)
    assert features.shape == (2, 40, 16, 16) and head(features).shape == (2, 24)
    big = torch.nn.functional.interpolate(images, scale_factor=2, mode="bilinear", align_corners=False)
    torch.testing.assert_close(features, coarse(big))
    assert trunk_id(enlarged) != trunk_id(coarse)
    both, _ = make_camera_encoder("efficientnet_lite0", 24, trunk_stride=4, trunk_scale=2)
    assert both(images).shape == (2, 24, 32, 32)
    assert len({trunk_id(enlarged), trunk_id(both), trunk_id(coarse)}) == 3


@pytest.mark.parametrize("stride, scale", [(2, 1), (16, 1), (8, 3), (8, 0)])
def test_a_trunk_cut_or_scale_it_does_not_make_is_refused(stride, scale):
    message = (rf"trunk_stride {stride}: expected one of \[4, 8\]" if stride not in (4, 8)
               else rf"trunk_scale {scale}: expected one of \[1, 2\]")
    with pytest.raises(ValueError, match=message):
        make_camera_encoder("efficientnet_lite0", 24, trunk_stride=stride, trunk_scale=scale)
    with pytest.raises(ValueError, match="the 'cnn' encoder's strides are its own"):
        make_camera_encoder("cnn", 24, trunk_stride=4)
    with pytest.raises(ValueError, match="the 'cnn' encoder's strides are its own"):
        make_camera_encoder("cnn", 24, trunk_scale=2)


@pytest.mark.parametrize("convs", [(), ((12, 3),), ((16, 2),), ((0, 3),)])
def test_a_trunk_head_it_cannot_build_is_refused(convs):
    with pytest.raises(ValueError, match="channels a multiple of 8 .* and an odd kernel"):
        make_camera_encoder("efficientnet_lite0", 24, trunk_head=convs)


def test_the_cnn_encoder_keeps_its_own_convs():
    with pytest.raises(ValueError, match="the 'cnn' encoder's convs are its own"):
        make_camera_encoder("cnn", 24, trunk_head=((64, 3),))


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


def test_a_film_head_starts_as_its_unconditioned_twin_and_needs_the_prompt():
    _, film = make_camera_encoder("cnn", 24, film_dim=6)
    _, plain = make_camera_encoder("cnn", 24)
    plain.load_state_dict({k: v for k, v in film.state_dict().items() if not k.startswith("film.")})
    images = torch.rand(3, 3, 32, 32)
    torch.testing.assert_close(film(images, torch.randn(3, 6)), plain(images))  # FiLM starts as the identity
    with pytest.raises(ValueError, match="conditioned on the prompt"):
        film(images)


def _two_squares(n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(n, 3, 16, 16) maps with a red and a blue 3x3 square at random cells, a one-hot prompt naming one of the
    two, and the named square's centre in [-1, 1]."""
    maps = torch.zeros(n, 3, 16, 16)
    named = torch.randint(0, 2, (n,), generator=generator)
    centres = torch.zeros(n, 2, 2)
    for i in range(n):
        cells = torch.randperm(4, generator=generator)[:2]  # two of four quadrants: the squares never overlap
        for colour, cell in zip((0, 2), cells.tolist()):
            row = 8 * (cell // 2) + int(torch.randint(0, 5, (1,), generator=generator))
            col = 8 * (cell % 2) + int(torch.randint(0, 5, (1,), generator=generator))
            maps[i, colour, row: row + 3, col: col + 3] = 1.0
            centres[i, colour // 2] = torch.tensor([col + 1, row + 1]) / 7.5 - 1.0
    return maps, torch.nn.functional.one_hot(named, 2).float(), centres[torch.arange(n), named]


def test_a_film_head_learns_to_locate_the_object_its_prompt_names():
    """Two squares in sight, the prompt names one: its position is learnable only through the prompt."""
    torch.manual_seed(0)
    generator = torch.Generator().manual_seed(0)
    head = CameraHead(3, 32, ((16, 3, 1),), keypoints=8, film_dim=2)  # a 16x16 grid of 3 channels, no striding
    readout = torch.nn.Linear(32, 2)
    optimizer = torch.optim.Adam([*head.parameters(), *readout.parameters()], lr=3e-3)
    for _ in range(400):
        maps, prompt, target = _two_squares(64, generator)
        loss = torch.nn.functional.mse_loss(readout(head(maps, prompt)), target)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    maps, prompt, target = _two_squares(256, generator)
    with torch.no_grad():
        error = (readout(head(maps, prompt)) - target).norm(dim=1).median()
        swapped = (readout(head(maps, prompt.flip(1))) - target).norm(dim=1).median()
    assert error < 0.15 and swapped > 0.5, (error, swapped)  # it finds the named square, not the other


def test_colour_needs_a_frozen_trunk():
    with pytest.raises(ValueError, match="image_colour needs a frozen trunk"):
        make_camera_encoder("cnn", 24, colour=True)

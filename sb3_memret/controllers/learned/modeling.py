"""The learned controller's network: prompt tokens, state (and camera images) in, an action chunk out.

The prompt arrives as frozen MiniLM per-token features; multi-head attention pooling with learned
queries lets the network find the one token that matters (the layer digit), which a pooled
sentence vector blurs. State is normalised with the demonstrations' statistics, kept as buffers
so a checkpoint carries them. A camera policy also estimates, from its image vectors alone, the state
entries a robot does not read of itself (``perceived_names``: where the cube is, how far each drawer is
open), trained on the simulator's labels: the action head reads those estimates, as a modular
visuomotor policy reads its detector. With ``pointer`` the action head also reads the estimates of the one object
the prompt points at (``ObjectPointer``), with ``perception_state`` the perception head reads the hand's pose too, and
with ``image_film`` the camera heads read the prompt too. An MLP maps the concatenation to ``chunk_len`` x
``action_dim``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file
from torch import nn
from torch.nn import functional as F

from sb3_memret.controllers.learned.configuration import LearnedPolicyConfig, perceived_objects
from sb3_memret.controllers.learned.vision import make_camera_encoder
from sb3_memret.common.weights import WeightsNotLoadedError, check_loaded

WEIGHTS_FILE = "model.safetensors"
MIN_STATE_STD = 1e-2  # features that never vary in the demos (the cube's tilt) are not blown up
PERCEPTION_HIDDEN = 256  # the hidden layer of a perception head that reads the state too (perception_state)


class AttentionPool(nn.Module):
    """Learned queries (one per head) attend over token features: (B, T, D), mask (B, T) -> (B, text_dim)."""

    def __init__(self, token_dim: int, text_dim: int, heads: int):
        super().__init__()
        self.heads, self.head_dim = heads, text_dim // heads
        self.keys = nn.Linear(token_dim, text_dim)
        self.values = nn.Linear(token_dim, text_dim)
        self.queries = nn.Parameter(torch.randn(heads, self.head_dim) / math.sqrt(self.head_dim))
        self.norm = nn.LayerNorm(text_dim)

    def forward(self, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        b, t, _ = tokens.shape
        keys = self.keys(tokens).view(b, t, self.heads, self.head_dim)
        values = self.values(tokens).view(b, t, self.heads, self.head_dim)
        scores = torch.einsum("bthd,hd->bht", keys, self.queries) / math.sqrt(self.head_dim)
        weights = scores.masked_fill(~mask[:, None, :], float("-inf")).softmax(dim=-1)
        return self.norm(torch.einsum("bht,bthd->bhd", weights, values).reshape(b, -1))


class ObjectPointer(nn.Module):
    """Attention from the prompt over the perceived objects: (B, perceived) estimates and (B, text_dim) prompts ->
    (B, fields), the estimates of the object the prompt points at (softly). With nine cubes in sight, an MLP
    left to pick the named one's coordinates out of all 36 estimates went to another cube in most failures."""

    def __init__(self, perceived_names: tuple[str, ...], text_dim: int):
        super().__init__()
        objects, fields = perceived_objects(perceived_names)
        index = [[perceived_names.index(f"{obj}_{name}") for name in fields] for obj in objects]
        self.register_buffer("index", torch.tensor(index), persistent=False)  # (objects, fields), rebuilt from names
        self.query = nn.Linear(text_dim, text_dim)
        self.keys = nn.Parameter(torch.randn(len(objects), text_dim) / math.sqrt(text_dim))

    def weights(self, prompt: torch.Tensor) -> torch.Tensor:
        """(B, text_dim) prompts -> (B, objects): how much each perceived object is the one pointed at."""
        return (self.query(prompt) @ self.keys.T / math.sqrt(self.keys.shape[1])).softmax(dim=-1)

    def forward(self, perceived: torch.Tensor, prompt: torch.Tensor) -> torch.Tensor:
        return torch.einsum("bo,bof->bf", self.weights(prompt), perceived[:, self.index])


def pointer_ambiguity(weights: torch.Tensor) -> torch.Tensor:
    """(P, objects) pointer weights of P distinct prompts -> log(objects) minus the mutual information between the
    prompt and the object pointed at (the entropy of the mean weights less the mean entropy of each prompt's): 0
    when each prompt points sharply at an object of its own, log(objects) when all point alike or spread evenly.
    Logged by ``finetune``: a pointer that learned reads ~0.15 on RememberColor9, one that failed 1.8-2.0."""
    def entropy(probs: torch.Tensor) -> torch.Tensor:
        return torch.distributions.Categorical(probs=probs).entropy()

    return math.log(weights.shape[1]) - entropy(weights.mean(dim=0)) + entropy(weights).mean()


class LearnedPolicy(nn.Module):
    """Predicts an action chunk (B, chunk_len, action_dim) from state, prompt tokens and optional images.

    Each camera has its own trainable head; a frozen pretrained trunk (``image_encoder``), if any, is shared,
    lives outside the checkpoint (its file's SHA-256 is in the config) and is checked when loaded.
    """

    TRUNK = "trunk."  # state-dict prefix of the frozen trunk's tensors, never saved

    def __init__(self, config: LearnedPolicyConfig):
        super().__init__()
        self.config = config
        self.register_buffer("state_mean", torch.zeros(config.state_dim))
        self.register_buffer("state_std", torch.ones(config.state_dim))
        self.text = AttentionPool(config.token_dim, config.text_dim, config.text_heads)
        self.trunk: nn.Module | None = None
        heads = []
        for _ in config.image_features:
            trunk, head = make_camera_encoder(config.image_encoder, config.image_dim, config.trunk_sha256 or None,
                                              config.keypoints, config.image_colour,
                                              config.text_dim if config.image_film else 0, config.image_head,
                                              config.trunk_stride, config.trunk_scale)
            heads.append(head)
            if trunk is not None and self.trunk is None:
                self.trunk = trunk
                config.trunk_sha256 = trunk.sha256
        self.cameras = nn.ModuleList(heads)
        vision_dim = config.image_dim * len(config.image_features)
        n_perceived = len(config.perceived_names)
        self.perception: nn.Module | None = None
        if n_perceived:  # a policy without perceived entries holds none of these tensors (older checkpoints load)
            self.register_buffer("perceived_mean", torch.zeros(n_perceived))
            self.register_buffer("perceived_std", torch.ones(n_perceived))
            self.perception = (nn.Sequential(nn.Linear(vision_dim + config.state_dim, PERCEPTION_HIDDEN), nn.GELU(),
                                             nn.Linear(PERCEPTION_HIDDEN, n_perceived))
                               if config.perception_state else nn.Linear(vision_dim, n_perceived))
        self.pointer: ObjectPointer | None = None
        if config.pointer:
            if not n_perceived:
                raise ValueError("pointer needs perceived entries to point at: a camera policy trained with its "
                                 "perception head (perception_coef > 0) on a task whose state has objects to perceive")
            self.pointer = ObjectPointer(config.perceived_names, config.text_dim)
        width = config.state_dim + config.text_dim + vision_dim + n_perceived + config.pointer_fields
        layers: list[nn.Module] = []
        for _ in range(config.n_layers):
            layers += [nn.Linear(width, config.hidden_dim), nn.GELU()]
            width = config.hidden_dim
        layers.append(nn.Linear(width, config.chunk_len * config.action_dim))
        self.head = nn.Sequential(*layers)

    def set_state_stats(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        """Normalise states with the demonstrations' mean and std (std floored at MIN_STATE_STD)."""
        self.state_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.state_std.copy_(torch.as_tensor(std, dtype=torch.float32).clamp(min=MIN_STATE_STD))

    def set_perceived_stats(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        """Scale of the perceived entries' labels: the perception head estimates them normalised."""
        if self.perception is None:
            raise ValueError("the policy estimates no perceived entries (config.perceived_names is empty)")
        self.perceived_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.perceived_std.copy_(torch.as_tensor(std, dtype=torch.float32).clamp(min=MIN_STATE_STD))

    def encode_prompts(self, tokens: torch.Tensor, token_mask: torch.Tensor) -> torch.Tensor:
        """(P, T, 384) token features and (P, T) mask -> (P, text_dim): one vector per prompt."""
        return self.text(tokens, token_mask)

    @torch.no_grad()
    def camera_features(self, images: list[torch.Tensor]) -> list[torch.Tensor]:
        """Per camera (B, 3, S, S) images in [0, 1] -> what the heads read: the frozen trunk's feature maps, or
        the images themselves when the encoder is trained from pixels."""
        if len(images) != len(self.cameras):
            raise ValueError(f"the policy reads {len(self.cameras)} cameras {list(self.config.image_features)}, "
                             f"got {len(images)} image batches")
        return [self.trunk(image) for image in images] if self.trunk is not None else list(images)

    def encode_cameras(self, camera_features: list[torch.Tensor] | None,
                       prompt: torch.Tensor | None = None) -> torch.Tensor:
        """Per camera ``camera_features`` -> (B, image_dim x cameras): what the action head sees of the images.
        Heads conditioned on the prompt (``config.image_film``) also read the (B, text_dim) ``encode_prompts``
        vectors."""
        camera_features = camera_features or []
        if self.config.image_film and prompt is None:
            raise ValueError("this policy's camera heads are conditioned on the prompt (image_film): pass the "
                             "encode_prompts vectors to encode_cameras")
        if len(camera_features) != len(self.cameras):
            raise ValueError(f"the policy reads {len(self.cameras)} cameras {list(self.config.image_features)}, "
                             f"got {len(camera_features)} feature batches")
        if not camera_features:
            return self.state_mean.new_zeros((0, 0))
        return torch.cat([head(features.float(), prompt) for head, features in zip(self.cameras, camera_features)],
                         dim=-1)

    def perceive(self, vision: torch.Tensor, state: torch.Tensor | None = None) -> torch.Tensor:
        """``encode_cameras`` vectors (and, for a head that reads it, ``perception_state``, the (B, state_dim) states)
        -> (B, len(perceived_names)) normalised estimates of the perceived entries. Where an object lies in the wrist
        camera's picture tells where it is on the table only with where the hand is: hence the state."""
        if self.perception is None:
            return vision.new_zeros((len(vision), 0))
        if self.config.perception_state:
            if state is None:
                raise ValueError("this policy's perception head reads the state too (perception_state): pass the "
                                 "states to perceive")
            vision = torch.cat([vision, (state - self.state_mean) / self.state_std], dim=-1)
        return self.perception(vision)

    @torch.no_grad()
    def estimate_perceived(self, camera_features: list[torch.Tensor], prompt: torch.Tensor,
                           state: torch.Tensor | None = None) -> torch.Tensor:
        """Per camera ``camera_features``, (B, text_dim) prompts (and (B, state_dim) states, for a head that reads
        them) -> (B, len(perceived_names)) estimates in the state's units: what the perception head makes of the
        images, for diagnosis."""
        estimates = self.perceive(self.encode_cameras(camera_features, prompt), state)
        return estimates * self.perceived_std + self.perceived_mean if self.perception is not None else estimates

    def decode(self, state: torch.Tensor, prompt: torch.Tensor, vision: torch.Tensor) -> torch.Tensor:
        """(B, state_dim) states, (B, text_dim) prompts and ``encode_cameras`` vectors -> action chunks. The action
        head reads the perception estimates as they are: only their labels train them."""
        parts = [(state - self.state_mean) / self.state_std, prompt]
        if self.cameras:
            perceived = self.perceive(vision, state).detach()
            parts += [vision, perceived]
            if self.pointer is not None:
                parts.append(self.pointer(perceived, prompt))
        out = self.head(torch.cat(parts, dim=-1))
        return out.view(-1, self.config.chunk_len, self.config.action_dim)

    def forward(self, state: torch.Tensor, prompt: torch.Tensor,
                camera_features: list[torch.Tensor] | None = None) -> torch.Tensor:
        """(B, state_dim) states, (B, text_dim) ``encode_prompts`` vectors, per camera ``camera_features``."""
        return self.decode(state, prompt, self.encode_cameras(camera_features, prompt))

    def losses(self, batch: "TrainingBatch") -> tuple[torch.Tensor, torch.Tensor]:
        """The three training terms on ``batch``: the action chunk's L1 error (``chunk_loss``), the perception head's
        MSE on the labelled perceived entries (0 without them) and the pointer's hindsight cross-entropy (0 without
        hindsight targets), which the finetune weighs and sums; and each frame's own action error (``frame_errors``,
        detached), which a finetune sampling by error keeps."""
        encoded = self.encode_prompts(batch.tokens, batch.token_mask)
        prompt = encoded[batch.prompt_of]
        vision = self.encode_cameras(batch.cameras, prompt)
        predicted = self.decode(batch.state, prompt, vision)
        acting = chunk_loss(predicted, batch.targets, batch.is_pad)
        seen = (masked_mse(self.perceive(vision, batch.state), batch.perceived, batch.perceived_mask)
                if batch.perceived is not None else acting.new_zeros(()))
        terms = torch.stack([acting, seen, self.hindsight_loss(encoded, batch.pointed)])
        return terms, frame_errors(predicted.detach(), batch.targets, batch.is_pad)

    def hindsight_loss(self, encoded: torch.Tensor, pointed: torch.Tensor | None) -> torch.Tensor:
        """Cross-entropy of the pointer weights of the (P, text_dim) ``encoded`` prompts against ``pointed``, each
        prompt's hindsight object (-1: none), over the prompts that have one (0 when none has)."""
        if pointed is None or not (pointed >= 0).any():
            return encoded.new_zeros(())
        has = pointed >= 0
        pointing = self.pointer.weights(encoded[has])
        return F.nll_loss(torch.log(pointing.clamp_min(1e-8)), pointed[has])

    def save_pretrained(self, folder: str | Path) -> Path:
        """Write ``config.json`` and ``model.safetensors`` into ``folder``."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self.config.save(folder)
        save_file({k: v.detach().cpu().contiguous() for k, v in self.trainable_state().items()}, folder / WEIGHTS_FILE)
        return folder

    def trainable_state(self) -> dict[str, torch.Tensor]:
        """The state dict without the frozen trunk: what a checkpoint holds."""
        return {k: v for k, v in self.state_dict().items() if not k.startswith(self.TRUNK)}

    @classmethod
    def from_pretrained(cls, folder: str | Path, device: str | torch.device = "cpu") -> "LearnedPolicy":
        """Load a checkpoint and check every tensor landed by name, shape and value."""
        folder = Path(folder).expanduser()
        if not folder.is_dir():
            raise FileNotFoundError(f"learned controller checkpoint {str(folder)!r} is not a folder; expected what "
                                    "`sb3-memret finetune` writes (config.json, model.safetensors)")
        config = LearnedPolicyConfig.load(folder)
        if not (folder / WEIGHTS_FILE).is_file():
            raise WeightsNotLoadedError(f"no {WEIGHTS_FILE} in {str(folder)!r}")
        model = cls(config)
        saved = load_file(folder / WEIGHTS_FILE)
        try:
            model.load_state_dict(saved, strict=False)
        except RuntimeError as err:  # a size mismatch
            raise WeightsNotLoadedError(f"checkpoint {folder} does not fit its config: {err}") from err
        check_loaded(model.trainable_state(), saved, f"learned controller checkpoint {folder}")
        return model.to(device).eval()


@dataclass
class TrainingBatch:
    """Demonstration frames as the policy trains on them: B frames and the P distinct prompts they were acted on."""

    state: torch.Tensor  # (B, state_dim) the state entries the policy reads, in the state's units
    cameras: list[torch.Tensor]  # per camera, what ``camera_features`` gives (a frozen trunk's maps, or images)
    tokens: torch.Tensor  # (P, T, token_dim) the distinct prompts' token features
    token_mask: torch.Tensor  # (P, T)
    prompt_of: torch.Tensor  # (B,) each frame's prompt among the P
    targets: torch.Tensor  # (B, chunk_len, action_dim) the expert's labels
    is_pad: torch.Tensor  # (B, chunk_len) the chunk steps past the episode's end
    perceived: torch.Tensor | None = None  # (B, K) the perceived entries' normalised labels (None: no perception)
    perceived_mask: torch.Tensor | None = None  # (B, K) which of them the frame's task labels
    pointed: torch.Tensor | None = None  # (P,) each prompt's hindsight object (-1: none; None: no hindsight)


def masked_mse(predicted: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The mean squared error over the entries ``mask`` marks (a frame's task's own perceived entries)."""
    weight = mask.to(predicted.dtype)
    return ((predicted - target) ** 2 * weight).sum() / weight.sum().clamp_min(1.0)


def step_errors(predicted: torch.Tensor, target: torch.Tensor, is_pad: torch.Tensor) -> torch.Tensor:
    """(B, H) each chunk step's L1 error over the action, 0 at the steps past the episode's end (``is_pad``)."""
    return F.l1_loss(predicted, target, reduction="none").mean(dim=-1) * (~is_pad).float()


def chunk_loss(predicted: torch.Tensor, target: torch.Tensor, is_pad: torch.Tensor) -> torch.Tensor:
    """Mean L1 error over the chunk steps that lie inside the episode (``is_pad`` (B, H) marks the rest)."""
    return step_errors(predicted, target, is_pad).sum() / (~is_pad).sum().clamp(min=1)


def frame_errors(predicted: torch.Tensor, target: torch.Tensor, is_pad: torch.Tensor) -> torch.Tensor:
    """(B,) each frame's mean L1 error over its chunk steps inside the episode (0 for a chunk wholly past it)."""
    return step_errors(predicted, target, is_pad).sum(dim=1) / (~is_pad).sum(dim=1).clamp(min=1)

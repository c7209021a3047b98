"""A finetune's recipe as a file: which policy, what it reads, its network's options and its optimisation.

``sb3-memret finetune DATASETS --config FILE`` reads one (``zoo_configs/finetune_learned.yml`` by default, or
``finetune_pi05.yml`` for ``--policy pi05``); each shipped learned controller keeps the one it was trained with beside
its weights (``recipe.yml``). ``--set KEY=VALUE`` changes one key (``training.steps=4000``, ``model.pointer=true``).
Every key is checked before any data is read: an unknown key or a value out of range is refused, naming it and what
is accepted. Layout::

    policy: learned            # or pi05
    state: null                # full | proprio | harness (MIKASA's 7-D proprio); null: proprio with cameras, else full
    cameras: true              # read the datasets' camera images
    cache_features: true       # keep a frozen trunk's features on disk for the next finetune
    model: {...}               # the learned policy's network (MODEL_KEYS)
    training: {...}            # the optimisation (FinetuneSettings' fields)
    pi05: {...}                # pi05 only: its checkpoint, tokenizer, LoRA rank and device (Pi05Settings)
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping, Sequence

import yaml

from sb3_memret.controllers.learned.vision import TRUNK_HEAD, TRUNK_STRIDE
from sb3_memret.stage1.finetune import STATE_CHOICES, FinetuneSettings
from sb3_memret.training.config import ZOO_CONFIGS, read_yaml

POLICIES = ("learned", "pi05")
DEFAULT_CONFIGS = {policy: ZOO_CONFIGS / f"finetune_{policy}.yml" for policy in POLICIES}
# the learned policy's network options a recipe sets (LearnedPolicyConfig's fields of the same names); the rest of
# its config (what it reads, its prompt contract, its chunk length) comes from the datasets and the tasks
MODEL_KEYS: dict[str, tuple[type | tuple[type, ...], str]] = {
    "image_encoder": (str, "'cnn' or 'efficientnet_lite0'"),
    "image_dim": (int, "an integer >= 1 (per camera: what the action and perception heads read of it)"),
    "keypoints": (int, "an integer >= 1 (per camera: feature maps whose image coordinates its head reads)"),
    "image_head": (list, "a list of [channels, kernel] convs (a frozen trunk's camera heads)"),
    "trunk_stride": (int, "4 or 8 (where the frozen trunk is cut)"),
    "trunk_scale": (int, "1 or 2 (the picture enlarged before the frozen trunk)"),
    "image_colour": (bool, "true or false (the camera heads also read the image's colour)"),
    "image_film": (bool, "true or false (the camera heads' keypoints conditioned on the prompt)"),
    "pointer": (bool, "true or false (the action head also reads the object the prompt points at)"),
    "perception_state": (bool, "true or false (the perception head also reads the hand's pose)"),
    "hidden_dim": (int, "an integer >= 1 (the action head's width)"),
    "n_layers": (int, "an integer >= 1 (the action head's hidden layers)"),
    "text_dim": (int, "an integer >= 1 (the prompt vector's size)"),
}


@dataclass(frozen=True)
class Pi05Settings:
    """``--policy pi05``: LoRA on lerobot's PI05 from a pretrained checkpoint folder (and a local PaliGemma tokenizer
    folder), on one dataset."""

    pretrained: str | None = None
    tokenizer: str | None = None
    lora_rank: int = 16
    device: str = "cpu"

    def __post_init__(self) -> None:
        if self.lora_rank < 1:
            raise ValueError(f"pi05.lora_rank must be >= 1, got {self.lora_rank}")


@dataclass(frozen=True)
class FinetuneRecipe:
    """A validated finetune recipe (the module docstring gives the file's layout)."""

    policy: str = "learned"
    state: str | None = None
    cameras: bool = True
    cache_features: bool = True
    model: Mapping[str, Any] = field(default_factory=dict)
    training: FinetuneSettings = field(default_factory=FinetuneSettings)
    pi05: Pi05Settings = field(default_factory=Pi05Settings)

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise ValueError(f"policy {self.policy!r} is unknown; expected one of {list(POLICIES)}")
        if self.state is not None and self.state not in STATE_CHOICES:
            raise ValueError(f"state {self.state!r} is unknown; expected one of {list(STATE_CHOICES)} or null")
        if self.training.pointer_hindsight > 0 and not self.model.get("pointer", False):
            raise ValueError(f"training.pointer_hindsight={self.training.pointer_hindsight} trains the pointer: set "
                             "model.pointer: true")
        if self.model.get("image_encoder") == "cnn":
            trunk = {"image_head": [list(conv) for conv in TRUNK_HEAD], "trunk_stride": TRUNK_STRIDE, "trunk_scale": 1,
                     "image_colour": False}
            shaped = sorted(key for key, default in trunk.items() if key in self.model and self.model[key] != default)
            if shaped:
                raise ValueError(f"model.{', model.'.join(shaped)} shape a frozen trunk's camera heads; "
                                 "model.image_encoder 'cnn' has convs and strides of its own")
        if self.policy == "pi05" and (self.model or self.state is not None):
            raise ValueError("model and state set the learned policy's network and inputs; policy pi05 takes its "
                             "own (its pi05 section)")
        if self.policy == "learned" and self.pi05 != Pi05Settings():
            raise ValueError("the pi05 section sets policy pi05's checkpoint; a learned recipe takes none")

    def policy_options(self) -> dict[str, Any]:
        """The ``LearnedPolicyConfig`` options this recipe sets."""
        options = dict(self.model)
        if "image_head" in options:
            options["image_head"] = tuple(tuple(conv) for conv in options["image_head"])
        return options


def load_recipe(path: str | Path | None = None, policy: str = "learned", overrides: Sequence[str] = ()) -> FinetuneRecipe:
    """The recipe in ``path`` (None: the default one of ``policy``) with ``overrides`` (``KEY=VALUE``, the value read
    as YAML, ``KEY`` dotted into the sections: ``training.steps=4000``) applied; a ValueError names a bad key or
    value and what is accepted."""
    if path is None:
        if policy not in POLICIES:
            raise ValueError(f"policy {policy!r} is unknown; expected one of {list(POLICIES)}")
        path = DEFAULT_CONFIGS[policy]
    data = read_yaml(path, "finetune recipe")
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a finetune recipe is a mapping of keys, got {type(data).__name__}")
    for override in overrides:
        _apply(data, override, str(path))
    return parse_recipe(data, str(path))


def parse_recipe(data: Mapping[str, Any], where: str = "recipe") -> FinetuneRecipe:
    """A ``FinetuneRecipe`` from a mapping laid out as the module docstring says; a ValueError naming a bad key or
    value and what is accepted."""
    top = {f.name for f in fields(FinetuneRecipe)}
    unknown = sorted(set(data) - top)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; a finetune recipe has {sorted(top)}")
    for key in ("cameras", "cache_features"):
        if key in data and not isinstance(data[key], bool):
            raise ValueError(f"{where}: {key}={data[key]!r} is invalid; expected true or false")
    model = _section(data, "model", where)
    for key, value in model.items():
        if key not in MODEL_KEYS:
            raise ValueError(f"{where}: unknown key model.{key}; the model's keys are {sorted(MODEL_KEYS)}")
        types, expected = MODEL_KEYS[key]
        if isinstance(value, bool) != (types is bool) or not isinstance(value, types):
            raise ValueError(f"{where}: model.{key}={value!r} is invalid; expected {expected}")
    try:
        training = FinetuneSettings(**_typed(_section(data, "training", where), FinetuneSettings, "training", where))
        pi05 = Pi05Settings(**_typed(_section(data, "pi05", where), Pi05Settings, "pi05", where))
        return FinetuneRecipe(data.get("policy", "learned"), data.get("state"), data.get("cameras", True),
                              data.get("cache_features", True), model, training, pi05)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None


def _section(data: Mapping[str, Any], name: str, where: str) -> dict[str, Any]:
    section = data.get(name) or {}
    if not isinstance(section, dict):
        raise ValueError(f"{where}: {name} must be a mapping of keys, got {section!r}")
    return dict(section)


def _typed(values: dict[str, Any], cls: type, name: str, where: str) -> dict[str, Any]:
    """``values`` checked against the dataclass ``cls``'s fields: known keys only, each of its field's type."""
    kinds = {f.name: f.type for f in fields(cls)}
    for key, value in values.items():
        if key not in kinds:
            raise ValueError(f"unknown key {name}.{key}; its keys are {sorted(kinds)}")
        kind = str(kinds[key])
        if kind == "float" and isinstance(value, str):  # YAML reads 1e-3 (no dot) as a string
            try:
                values[key] = value = float(value)
            except ValueError:
                pass
        ok = {"int": isinstance(value, int) and not isinstance(value, bool),
              "float": isinstance(value, (int, float)) and not isinstance(value, bool),
              "str": isinstance(value, str), "str | None": value is None or isinstance(value, str)}.get(kind, True)
        if not ok:
            raise ValueError(f"{name}.{key}={value!r} is invalid; expected {kind.replace(' | None', ' or null')}")
    return values


def _apply(data: dict[str, Any], override: str, where: str) -> None:
    """Set ``KEY=VALUE`` in ``data``: the key dotted into a section, the value read as YAML."""
    key, sep, raw = override.partition("=")
    if not sep or not key:
        raise ValueError(f"{override!r} is not KEY=VALUE (e.g. training.steps=4000 or model.pointer=true)")
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        raise ValueError(f"{override!r}: {raw!r} is not a YAML value") from None
    *sections, last = key.split(".")
    target = data
    for section in sections:
        target = target.setdefault(section, {})
        if not isinstance(target, dict):
            raise ValueError(f"{override!r}: {section!r} in {where} is not a section")
    target[last] = value


__all__ = ["DEFAULT_CONFIGS", "FinetuneRecipe", "MODEL_KEYS", "POLICIES", "Pi05Settings", "load_recipe", "parse_recipe"]

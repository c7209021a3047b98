"""What a learned controller checkpoint was trained with: sizes, inputs, and its training prompts."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from sb3_memret.controllers.learned.vision import (IMAGE_ENCODERS, KEYPOINTS, TRUNK_HEAD, TRUNK_STRIDE, check_trunk_head,
                                                   check_trunk_scale, check_trunk_stride)
from sb3_memret.controllers.observation import ACTION_DIM, IMAGE_KEYS, STATE_NAMES
from sb3_memret.controllers.prompts import PromptTemplate

CONFIG_FILE = "config.json"
POINTER_FIELDS = ("x", "y", "z", "visible")  # the entries of one perceived object, ``<object>_<field>``
POSITION_FIELDS = POINTER_FIELDS[:3]  # what every object a pointer points at must have
POLICY_TYPE = "sb3_memret_learned"


@dataclass
class LearnedPolicyConfig:
    """Sizes of the network and the contract it was trained under.

    ``instructions`` and ``fact_templates`` are the templates of the training prompts (every
    prompt is checked against them before the policy acts, ``prompt_template``); ``training_prompts`` the exact prompts
    the demonstrations held, for the record. ``task`` is the task whose observation layout the policy
    reads; ``state_names`` the entries of that layout's state it takes (a camera-reading controller takes
    only what a robot reads of itself), by name, so a layout that moves them is refused, not misread.
    ``perceived_names``: the layout's entries a camera policy estimates from its images (the simulator's
    detection, drawer openings), labelled by the simulator at training only; its action head reads the estimates.
    ``tasks``: every task a multi-task controller serves, trained on their demonstrations together (``task`` is the
    first; ``state_names`` are in every one's layout, ``perceived_names`` the union of the entries each lacks);
    empty for a controller of ``task`` alone.
    """

    task: str = "drawer"
    tasks: tuple[str, ...] = ()
    state_names: tuple[str, ...] = STATE_NAMES
    state_dim: int = len(STATE_NAMES)
    action_dim: int = ACTION_DIM
    chunk_len: int = 32
    token_dim: int = 384  # MiniLM hidden size
    text_dim: int = 128
    text_heads: int = 4
    hidden_dim: int = 512
    n_layers: int = 3
    image_features: tuple[str, ...] = ()  # camera features read, empty for a state-only policy
    perceived_names: tuple[str, ...] = ()  # state entries estimated from the cameras (never read from the state)
    image_size: int = 128  # cameras are area-resized to this size (the demonstrations' stored size)
    image_dim: int = 64  # per camera: what the action and perception heads read of it
    keypoints: int = KEYPOINTS  # per camera: feature maps whose expected image coordinates its head reads
    image_encoder: str = "cnn"  # one of vision.IMAGE_ENCODERS
    image_head: tuple[tuple[int, int], ...] = TRUNK_HEAD  # a frozen trunk's head: (channels, kernel) of each conv
    trunk_stride: int = TRUNK_STRIDE  # where the frozen trunk is cut: its maps are 1/stride of the picture's side
    trunk_scale: int = 1  # the picture is enlarged this many times before the frozen trunk (finer maps)
    image_colour: bool = False  # a frozen trunk's heads also read the image's colour on the trunk's grid
    image_film: bool = False  # the camera heads' keypoints are conditioned on the prompt (FiLM)
    pointer: bool = False  # the action head also reads the perceived entries of the object the prompt points at
    perception_state: bool = False  # the perception head also reads the state (the hand's pose), through a hidden layer
    trunk_sha256: str = ""  # the frozen pretrained trunk's weights file, for encoders that have one
    action_convention: str = "pd_ee_delta_pose"
    robot: str | None = None  # the robot its training cameras showed (ManiSkill robot uid); None: not recorded
    instructions: tuple[str, ...] = ()  # the finetune sets them from its tasks' and datasets' prompts
    fact_templates: tuple[str, ...] = ()
    training_prompts: tuple[str, ...] = ()
    type: str = POLICY_TYPE

    def __post_init__(self) -> None:
        for name in ("tasks", "state_names", "image_features", "perceived_names", "instructions", "fact_templates",
                     "training_prompts"):
            setattr(self, name, tuple(getattr(self, name)))
        self.image_head = tuple(tuple(conv) for conv in self.image_head)  # JSON stores lists
        check_trunk_head(self.image_head)
        check_trunk_stride(self.trunk_stride)
        check_trunk_scale(self.trunk_scale)
        if self.tasks and (self.tasks[0] != self.task or len(set(self.tasks)) != len(self.tasks)):
            raise ValueError(f"tasks {list(self.tasks)} must be distinct and start with task {self.task!r}")
        if self.state_dim != len(self.state_names):
            raise ValueError(f"state_dim {self.state_dim} does not match the {len(self.state_names)} state_names")
        if self.image_encoder not in IMAGE_ENCODERS:
            raise ValueError(f"unknown image_encoder {self.image_encoder!r}; expected one of {list(IMAGE_ENCODERS)}")
        unknown = set(self.image_features) - set(IMAGE_KEYS)
        if unknown:
            raise ValueError(f"unknown image features {sorted(unknown)}; the task's cameras are {sorted(IMAGE_KEYS)}")
        if self.perceived_names and not self.image_features:
            raise ValueError(f"perceived_names {list(self.perceived_names)} need cameras to be estimated from; "
                             "image_features is empty")
        if self.pointer and self.perceived_names:
            perceived_objects(self.perceived_names)  # entries grouped per object, or a clear error
        both = sorted(set(self.perceived_names) & set(self.state_names))
        if both:
            raise ValueError(f"entries {both} are both read from the state and estimated from the cameras")
        if min(self.chunk_len, self.hidden_dim, self.n_layers, self.text_dim, self.text_heads, self.image_dim,
               self.keypoints) < 1:
            raise ValueError(f"sizes must be positive: {self}")
        if self.text_dim % self.text_heads:
            raise ValueError(f"text_dim {self.text_dim} must be a multiple of text_heads {self.text_heads}")

    @property
    def pointer_fields(self) -> int:
        """How many entries the pointer hands the action head: one object's (0 without a pointer)."""
        return len(perceived_objects(self.perceived_names)[1]) if self.pointer else 0

    @property
    def served_tasks(self) -> tuple[str, ...]:
        """The tasks whose observations and prompts the controller was trained on."""
        return self.tasks or (self.task,)

    def prompt_template(self, fields: tuple[tuple[str, str], ...] = ()) -> PromptTemplate:
        """The prompt contract it was trained under, its number fields as its task words them (``fields``)."""
        if not self.instructions:
            raise ValueError("the config names no instructions: a learned policy acts on the prompts its finetune "
                             "recorded (instructions, fact_templates)")
        return PromptTemplate(self.instructions, self.fact_templates, tuple(fields))

    def save(self, folder: Path) -> None:
        (folder / CONFIG_FILE).write_text(json.dumps(asdict(self), indent=2) + "\n")

    @classmethod
    def load(cls, folder: Path) -> "LearnedPolicyConfig":
        path = folder / CONFIG_FILE
        if not path.is_file():
            raise FileNotFoundError(f"no {CONFIG_FILE} in {str(folder)!r}: not a learned controller checkpoint "
                                    "(sb3-memret finetune writes one)")
        data: dict[str, Any] = json.loads(path.read_text())
        if data.get("type") != POLICY_TYPE:
            raise ValueError(f"{path} describes a {data.get('type')!r} policy, not {POLICY_TYPE!r}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"{path} has unknown keys {unknown}; accepted {sorted(known)}")
        return cls(**data)


def perceived_objects(names: tuple[str, ...]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(objects, fields) of perceived entries named ``<object>_<field>`` (fields from POINTER_FIELDS): MIKASA's
    ``cube_red_x`` ... ``cube_teal_visible``. The fields are those every object has, which must include its
    position: a policy across tasks whose objects differ in a flag (TakeItBack's cube has no ``visible``) points
    with the position alone. Entries of no such name (Rotate's ``peg_yaw``) are left out of the pointer; the action
    head reads their estimates all the same. A ValueError names what does not fit."""
    objects: dict[str, set[str]] = {}
    for name in names:
        obj, _, field_name = name.rpartition("_")
        if obj and field_name in POINTER_FIELDS:
            objects.setdefault(obj, set()).add(field_name)
    if len(objects) < 2:
        raise ValueError(f"pointer needs two or more perceived objects, entries named <object>_<field> with a field "
                         f"in {list(POINTER_FIELDS)}; got {sorted(objects)} of {len(names)} perceived entries")
    unplaced = {obj: sorted(set(POSITION_FIELDS) - have) for obj, have in objects.items() if
                not set(POSITION_FIELDS) <= have}
    if unplaced:
        raise ValueError(f"pointer needs every perceived object's position {list(POSITION_FIELDS)}; missing {unplaced}")
    common = set.intersection(*objects.values())
    return tuple(objects), tuple(f for f in POINTER_FIELDS if f in common)

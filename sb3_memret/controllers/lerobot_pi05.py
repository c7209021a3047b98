"""π0.5 run in-process with lerobot's ``PI05Policy``, from local folders only, verified after loading.

The checkpoint folder is what ``PI05Policy.save_pretrained`` plus the policy's processor pipelines
write (``config.json``, ``model.safetensors``, ``policy_preprocessor.json``,
``policy_postprocessor.json`` and their normalisation stats); the optional adapter folder is what
peft's ``save_pretrained`` writes (``adapter_config.json``, ``adapter_model.safetensors``). The
tokenizer folder replaces the gated hub tokenizer the processors name. lerobot's loader warns and
returns a randomly initialised model when weights fail to load, and peft skips adapter tensors it
cannot place; so after loading, every weight and every adapter tensor is compared by name, shape
and value with the files, and any difference raises.

lerobot (a dependency of sb3-memret) is imported only when this controller is built: it takes
seconds to import.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from sb3_memret.controllers.base import RENDER_HINT, ControllerSpec, FrozenController, Obs, as_numpy
from sb3_memret.controllers.weights import WeightsNotLoadedError, check_loaded
from sb3_memret.prompts import ParsedPrompt, PromptTemplate

# lerobot's LIBERO feature names for the two cameras, mapped to the task's cameras.
LIBERO_CAMERAS = {"observation.images.image": "base_camera", "observation.images.wrist_image": "hand_camera"}
STATE_KEY, ACTION_KEY, TASK_KEY = "observation.state", "action", "task"
STATE_DIM = 8
WEIGHTS_FILE, ADAPTER_FILE = "model.safetensors", "adapter_model.safetensors"


class LeRobotPi05Controller(FrozenController):
    """lerobot's PI05Policy (plus an optional LoRA adapter) acting on the task's two cameras and 8-D state.

    ``reset(seeds)`` seeds one noise generator per env, so an episode's action chunks depend on
    its seed and observations only.
    """

    def __init__(
        self,
        checkpoint: str | Path,
        adapter: str | Path | None = None,
        tokenizer: str | Path | None = None,
        device: str = "cpu",
        cameras: Mapping[str, str] = LIBERO_CAMERAS,
        prompt_template: PromptTemplate | None = None,
    ):
        self.checkpoint = _folder(checkpoint, "checkpoint", WEIGHTS_FILE)
        PreTrainedConfig, PI05Policy, make_pre_post_processors = _import_lerobot()
        self.cameras = dict(cameras)
        config = PreTrainedConfig.from_pretrained(self.checkpoint, local_files_only=True)
        if config.type != "pi05":
            raise ValueError(f"checkpoint {self.checkpoint} holds a {config.type!r} policy, not 'pi05'")
        config.device = device
        _check_features(config, self.cameras, self.checkpoint)

        self.policy = PI05Policy.from_pretrained(self.checkpoint, config=config, local_files_only=True)
        saved = _saved_policy_state(self.policy, self.checkpoint)
        check_loaded(self.policy.state_dict(), saved, f"checkpoint {self.checkpoint}")
        self.adapter = None  # the PeftModel around the policy, when an adapter is applied
        if adapter is not None:
            self._load_adapter(_folder(adapter, "adapter", ADAPTER_FILE))
        self.policy.eval()

        overrides = {"device_processor": {"device": device}}
        if tokenizer is not None:
            overrides["tokenizer_processor"] = {"tokenizer_name": str(_folder(tokenizer, "tokenizer"))}
        self.preprocess, self.postprocess = make_pre_post_processors(
            config, pretrained_path=str(self.checkpoint), preprocessor_overrides=overrides,
            postprocessor_overrides={"device_processor": {"device": "cpu"}},
        )
        self.spec = ControllerSpec(
            action_convention="pd_ee_delta_pose",
            chunk_len=config.chunk_size,
            action_dim=config.output_features[ACTION_KEY].shape[0],
            needs_images=True,
            prompt_template=prompt_template or PromptTemplate(),
        )
        self._noise_shape = (config.chunk_size, config.max_action_dim)
        self._generators: list[torch.Generator] = []

    def _load_adapter(self, folder: Path) -> None:
        """Apply a peft LoRA adapter in place and check every one of its tensors landed."""
        from peft import PeftModel, get_peft_model_state_dict
        from safetensors.torch import load_file

        try:
            peft_model = PeftModel.from_pretrained(self.policy, str(folder), is_trainable=False)
        except RuntimeError as err:  # torch's size-mismatch report, raised from peft's load_state_dict
            raise WeightsNotLoadedError(f"LoRA adapter {folder} does not fit the policy: {err}") from err
        check_loaded(get_peft_model_state_dict(peft_model), load_file(folder / ADAPTER_FILE), f"LoRA adapter {folder}")
        self.adapter = peft_model  # the policy's modules now carry the LoRA layers

    def reset(self, seeds: Sequence[int]) -> None:
        self._generators = [torch.Generator().manual_seed(int(seed)) for seed in seeds]
        self.policy.reset()

    @torch.no_grad()
    def _act(self, obs: Obs, prompts: Sequence[str], parsed: Sequence[ParsedPrompt]) -> np.ndarray:
        if len(self._generators) != len(prompts):
            raise RuntimeError(
                f"reset() was called for {len(self._generators)} envs but act() got {len(prompts)} prompts")
        batch = self.preprocess(self._batch(obs, prompts))
        noise = torch.stack([torch.randn(self._noise_shape, generator=g) for g in self._generators])
        device = next(self.policy.parameters()).device
        chunks = self.policy.predict_action_chunk(batch, noise=noise.to(device))
        return as_numpy(self.postprocess(chunks))

    def _batch(self, obs: Obs, prompts: Sequence[str]) -> dict[str, Any]:
        """The lerobot batch: float CHW images in [0, 1] per camera feature, the 8-D state, the prompts."""
        batch: dict[str, Any] = {}
        for feature, camera in self.cameras.items():
            rgb = obs.get("sensor_data", {}).get(camera, {}).get("rgb")
            if rgb is None:
                raise ValueError(f"the observation has no {camera} image (sensor_data/{camera}/rgb), which π0.5 "
                                 f"reads as {feature}; " + RENDER_HINT)
            batch[feature] = torch.as_tensor(as_numpy(rgb)).permute(0, 3, 1, 2).float() / 255.0
        batch[STATE_KEY] = torch.as_tensor(as_numpy(obs["agent"]["eef_state"]), dtype=torch.float32)
        batch[TASK_KEY] = list(prompts)
        return batch


def _check_features(config: Any, cameras: Mapping[str, str], checkpoint: Path) -> None:
    """Refuse a checkpoint whose inputs or outputs are not the task's cameras, 8-D state and 7-D actions."""
    images = set(config.image_features)
    if images != set(cameras):
        raise ValueError(f"checkpoint {checkpoint} reads images {sorted(images)}, but the cameras are mapped to "
                         f"{sorted(cameras)}; pass cameras= mapping its image features to base_camera/hand_camera")
    state = config.input_features.get(STATE_KEY)
    if state is None or tuple(state.shape) != (STATE_DIM,):
        raise ValueError(f"checkpoint {checkpoint} takes {STATE_KEY} {state}; the task's eef_state is ({STATE_DIM},)")
    action = config.output_features.get(ACTION_KEY)
    if action is None or tuple(action.shape) != (7,):
        raise ValueError(f"checkpoint {checkpoint} emits {ACTION_KEY} {action}; pd_ee_delta_pose takes (7,) actions")


def _saved_policy_state(policy: Any, checkpoint: Path) -> dict[str, torch.Tensor]:
    """The checkpoint's tensors under the names lerobot loads them into (its own key fixes, ``model.`` prefix)."""
    from safetensors.torch import load_file

    fixed = policy._fix_pytorch_state_dict_keys(load_file(checkpoint / WEIGHTS_FILE), policy.config)
    return {key if key.startswith("model.") else f"model.{key}": value for key, value in fixed.items()}


def _folder(path: str | Path, what: str, required_file: str | None = None) -> Path:
    folder = Path(path).expanduser()
    if not folder.is_dir():
        raise FileNotFoundError(f"{what} folder {folder} does not exist (only local folders are read, never a hub)")
    if required_file is not None and not (folder / required_file).is_file():
        raise FileNotFoundError(f"{what} folder {folder} has no {required_file}")
    return folder


def _import_lerobot() -> tuple[Any, Any, Any]:
    """lerobot's (PreTrainedConfig, PI05Policy, make_pre_post_processors)."""
    from lerobot.configs import PreTrainedConfig
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.policies.pi05 import PI05Policy

    return PreTrainedConfig, PI05Policy, make_pre_post_processors

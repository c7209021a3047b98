"""π0.5 run in-process with lerobot's ``PI05Policy``, from local folders only, verified after loading.

The checkpoint folder is what ``PI05Policy.save_pretrained`` plus the policy's processor pipelines
write (``config.json``, ``model.safetensors``, ``policy_preprocessor.json``,
``policy_postprocessor.json`` and their normalisation stats); the optional adapter folder is what
peft's ``save_pretrained`` writes (``adapter_config.json``, ``adapter_model.safetensors``);
``sb3_memret.stage1.finetune_pi05`` writes both. The
tokenizer folder replaces the gated hub tokenizer the processors name. lerobot's loader warns and
returns a randomly initialised model when weights fail to load, and peft skips adapter tensors it
cannot place; so after loading, every weight and every adapter tensor is compared by name, shape
and value with the files, and any difference raises. A checkpoint's ``observation.state`` is either
LIBERO's 8-D end-effector state (lerobot's and openpi's LIBERO finetunes) or the project's 19-D
``observation_state`` (finetuned on the project's demonstrations); the batch carries the matching one.

lerobot (a dependency of sb3-memret) is imported only when this controller is built: it takes
seconds to import.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch

from sb3_memret.controllers.base import ControllerSpec, FrozenController, Obs, as_numpy
from sb3_memret.controllers.observation import (ACTION_DIM, ACTION_KEY, IMAGE_KEYS, STATE_DIM, STATE_KEY, TASK_KEY,
                                                camera_images, observation_state)
from sb3_memret.common.weights import WeightsNotLoadedError, check_loaded
from sb3_memret.controllers.prompts import ParsedPrompt, PromptTemplate

LIBERO_STATE_DIM = 8
WEIGHTS_FILE, ADAPTER_FILE = "model.safetensors", "adapter_model.safetensors"


def libero_state(obs: Obs) -> np.ndarray:
    """(B, 8) float32 end-effector state, the ``observation.state`` of LIBERO finetunes."""
    state = as_numpy(obs["agent"]["eef_state"])
    if state.ndim != 2 or state.shape[1] != LIBERO_STATE_DIM:
        raise ValueError(f"agent/eef_state has shape {state.shape}; expected (B, {LIBERO_STATE_DIM})")
    return state.astype(np.float32)


# The observation.state layouts a checkpoint may take, by size, and how each is read from the env observation.
STATE_READERS: Mapping[int, Callable[[Obs], np.ndarray]] = {LIBERO_STATE_DIM: libero_state,
                                                            STATE_DIM: observation_state}


class LeRobotPi05Controller(FrozenController):
    """lerobot's PI05Policy (plus an optional LoRA adapter) acting on the task's two cameras and the 8-D or
    19-D state its checkpoint takes.

    ``reset(seeds)`` seeds one noise generator per env, so an episode's action chunks depend on
    its seed and observations only.
    """

    def __init__(
        self,
        checkpoint: str | Path,
        adapter: str | Path | None = None,
        tokenizer: str | Path | None = None,
        device: str = "cpu",
        cameras: Mapping[str, str] = IMAGE_KEYS,
        *,
        prompt_template: PromptTemplate,
    ):
        self.checkpoint = local_folder(checkpoint, "checkpoint", WEIGHTS_FILE)
        from lerobot.policies.factory import make_pre_post_processors

        unknown = set(cameras.values()) - set(IMAGE_KEYS.values())
        if unknown:
            raise ValueError(f"cameras= maps features to {sorted(unknown)}; the task's cameras are "
                             f"{sorted(IMAGE_KEYS.values())}")
        self.cameras = dict(cameras)
        config = load_pi05_config(self.checkpoint, "checkpoint")
        config.device = device
        check_features(config, self.cameras, f"checkpoint {self.checkpoint}")
        self._read_state = STATE_READERS[config.input_features[STATE_KEY].shape[0]]

        self.policy = load_checked_policy(self.checkpoint, config, f"checkpoint {self.checkpoint}")
        self.adapter = None  # the PeftModel around the policy, when an adapter is applied
        if adapter is not None:
            self._load_adapter(local_folder(adapter, "adapter", ADAPTER_FILE))
        self.policy.eval()

        overrides = {"device_processor": {"device": device}}
        if tokenizer is not None:
            overrides["tokenizer_processor"] = {"tokenizer_name": str(local_folder(tokenizer, "tokenizer"))}
        self.preprocess, self.postprocess = make_pre_post_processors(
            config, pretrained_path=str(self.checkpoint), preprocessor_overrides=overrides,
            postprocessor_overrides={"device_processor": {"device": "cpu"}},
        )
        self.spec = ControllerSpec(
            action_convention="pd_ee_delta_pose",
            chunk_len=config.chunk_size,
            action_dim=config.output_features[ACTION_KEY].shape[0],
            needs_images=True,
            prompt_template=prompt_template,
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

    def reset_envs(self, env_ids: Sequence[int], seeds: Sequence[int]) -> None:
        self._check_env_ids(env_ids, seeds, len(self._generators))
        for i, seed in zip(env_ids, seeds):
            self._generators[i] = torch.Generator().manual_seed(int(seed))

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
        """The lerobot batch: float CHW images in [0, 1] per camera feature, the checkpoint's state, the prompts."""
        by_camera = {IMAGE_KEYS[feature]: image for feature, image in camera_images(obs).items()}
        batch: dict[str, Any] = {feature: torch.as_tensor(by_camera[camera]).permute(0, 3, 1, 2).float() / 255.0
                                 for feature, camera in self.cameras.items()}
        batch[STATE_KEY] = torch.as_tensor(self._read_state(obs))
        batch[TASK_KEY] = list(prompts)
        return batch


def load_pi05_config(folder: Path, what: str) -> Any:
    """The PI05Config in a local folder's config.json; another policy type raises."""
    from lerobot.configs import PreTrainedConfig

    config = PreTrainedConfig.from_pretrained(folder, local_files_only=True)
    if config.type != "pi05":
        raise ValueError(f"{what} {folder} holds a {config.type!r} policy, not 'pi05'")
    return config


def load_checked_policy(folder: Path, config: Any, what: str) -> Any:
    """``PI05Policy.from_pretrained`` on a local folder, then every weight compared with its model.safetensors."""
    from lerobot.policies.pi05 import PI05Policy

    policy = PI05Policy.from_pretrained(folder, config=config, local_files_only=True)
    check_loaded(policy.state_dict(), _saved_policy_state(policy, folder), what)
    return policy


def check_features(config: Any, cameras: Mapping[str, str], source: str) -> None:
    """Refuse features other than the mapped cameras, an 8-D or 19-D state (within the state padding) and
    7-D actions; ``source`` names what they come from."""
    images = set(config.image_features)
    if images != set(cameras):
        raise ValueError(f"{source} has image features {sorted(images)}, but the task's cameras are mapped to "
                         f"{sorted(cameras)} (LeRobotPi05Controller's cameras=: feature -> base_camera/hand_camera)")
    state = config.input_features.get(STATE_KEY)
    if state is None or len(state.shape) != 1 or state.shape[0] not in STATE_READERS:
        raise ValueError(f"{source} has {STATE_KEY} {state}; the controller builds LIBERO's ({LIBERO_STATE_DIM},) "
                         f"eef_state or the project's ({STATE_DIM},) observation_state")
    if state.shape[0] > config.max_state_dim:
        raise ValueError(f"{source} has a {state.shape[0]}-D {STATE_KEY}; PI05 pads states to at most "
                         f"max_state_dim={config.max_state_dim}")
    action = config.output_features.get(ACTION_KEY)
    if action is None or tuple(action.shape) != (ACTION_DIM,):
        raise ValueError(f"{source} has {ACTION_KEY} {action}; pd_ee_delta_pose takes ({ACTION_DIM},) actions")


def _saved_policy_state(policy: Any, checkpoint: Path) -> dict[str, torch.Tensor]:
    """The checkpoint's tensors under the names lerobot loads them into (its own key fixes, ``model.`` prefix)."""
    from safetensors.torch import load_file

    fixed = policy._fix_pytorch_state_dict_keys(load_file(checkpoint / WEIGHTS_FILE), policy.config)
    return {key if key.startswith("model.") else f"model.{key}": value for key, value in fixed.items()}


def local_folder(path: str | Path, what: str, required_file: str | None = None) -> Path:
    """``path`` as an existing local folder (holding ``required_file``), or FileNotFoundError naming it."""
    folder = Path(path).expanduser()
    if not folder.is_dir():
        raise FileNotFoundError(f"{what} folder {folder} does not exist (only local folders are read, never a hub)")
    if required_file is not None and not (folder / required_file).is_file():
        raise FileNotFoundError(f"{what} folder {folder} has no {required_file}")
    return folder


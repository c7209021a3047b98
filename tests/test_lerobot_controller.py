"""LeRobotPi05Controller: the strict load checks on plain torch modules, and a tiny random PI05 end to end."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from sb3_memret.tasks.drawer.prompts import TEMPLATE
from sb3_memret.common.weights import LoadReport, WeightsNotLoadedError, check_loaded, compare_tensors
from tiny_pi05 import TINY_WIDTH, build_tiny_pi05, tiny_sizes


# ------------------------------------------------------------ the checks, on plain torch modules
class Tiny(nn.Module):
    def __init__(self, tied: bool = False):
        super().__init__()
        self.embed = nn.Embedding(5, 3)
        self.head = nn.Linear(3, 5, bias=False)
        self.norm = nn.LayerNorm(3)
        if tied:
            self.head.weight = self.embed.weight


def saved_copy(module: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in module.state_dict().items()}


def test_exact_copy_passes():
    model = Tiny()
    assert compare_tensors(model.state_dict(), saved_copy(model)).ok
    check_loaded(model.state_dict(), saved_copy(model), "checkpoint x")


def test_missing_weight_raises():
    model = Tiny()
    saved = saved_copy(model)
    del saved["norm.bias"]
    with pytest.raises(WeightsNotLoadedError, match=r"checkpoint x was not loaded as saved: 1 missing: norm\.bias"):
        check_loaded(model.state_dict(), saved, "checkpoint x")


def test_values_left_at_initialisation_raise():
    """The known failure: the loader gave up quietly and the model kept its random weights."""
    saved = saved_copy(Tiny())  # another random initialisation (the norm's ones and zeros coincide)
    with pytest.raises(WeightsNotLoadedError, match=r"2 differing: embed\.weight, head\.weight$"):
        check_loaded(Tiny().state_dict(), saved, "checkpoint x")


def test_mismatched_shape_raises():
    model = Tiny()
    saved = {**saved_copy(model), "head.weight": torch.zeros(6, 3)}
    with pytest.raises(WeightsNotLoadedError, match=r"1 mismatched: head\.weight \(6, 3\)->\(5, 3\)"):
        check_loaded(model.state_dict(), saved, "checkpoint x")


def test_saved_dtype_is_cast_like_loading_does():
    model = Tiny().to(torch.bfloat16)
    saved = {k: v.float() for k, v in saved_copy(model).items()}
    assert compare_tensors(model.state_dict(), saved).ok


def test_tied_weights_stored_once_are_not_missing():
    model = Tiny(tied=True)
    saved = saved_copy(model)
    del saved["head.weight"]  # safetensors keeps one name per shared storage
    assert compare_tensors(model.state_dict(), saved).ok


def lora_state(model: nn.Module, prefix: str = "base_model.model.") -> dict[str, torch.Tensor]:
    """A peft-style adapter state: rank-2 LoRA factors for ``model``'s head, saved-file names."""
    gen = torch.Generator().manual_seed(0)
    return {f"{prefix}head.lora_A.weight": torch.randn(2, 3, generator=gen),
            f"{prefix}head.lora_B.weight": torch.randn(5, 2, generator=gen)}


def test_adapter_with_dropped_tensors_raises():
    """Adapter tensors whose names match no module are skipped by peft: missing and unexpected here."""
    held = {k: torch.zeros_like(v) for k, v in lora_state(Tiny()).items()}  # LoRA layers left at init
    saved = lora_state(Tiny(), prefix="base_model.model.model.")  # saved under another wrapping
    report = compare_tensors(held, saved)
    assert len(report.missing) == 2 and len(report.unexpected) == 2
    with pytest.raises(WeightsNotLoadedError,
                       match=r"LoRA adapter a was not loaded as saved: 2 missing: .*; 2 unexpected"):
        check_loaded(held, saved, "LoRA adapter a")


def test_adapter_with_a_missing_tensor_raises():
    saved = lora_state(Tiny())
    held = dict(saved)
    held["base_model.model.head.lora_B.weight"] = torch.zeros(5, 2)  # peft's zero init: the adapter does nothing
    partial = {k: v for k, v in saved.items() if "lora_B" not in k}
    with pytest.raises(WeightsNotLoadedError, match=r"1 missing: base_model\.model\.head\.lora_B\.weight"):
        check_loaded(held, partial, "LoRA adapter a")


def test_nothing_saved_raises():
    with pytest.raises(WeightsNotLoadedError, match="LoRA adapter a holds no tensors"):
        check_loaded(Tiny().state_dict(), {}, "LoRA adapter a")


def test_long_reports_are_cut():
    report = LoadReport(missing=tuple(f"w{i}" for i in range(20)), unexpected=(), mismatched=(), differing=())
    assert report.describe() == "20 missing: w0, w1, w2, w3, w4, w5, w6, w7 and 12 more"


# ---------------------------------------------------------------- a tiny random PI05, end to end
PROMPTS = ["pick out the cube. the cube is in drawer layer 2.", "pick out the cube."]


@pytest.fixture(scope="module")
def tiny_pi05(tmp_path_factory):
    """The tiny random PI05 checkpoint, its LoRA adapter and tokenizer (``tiny_pi05.py``)."""
    return build_tiny_pi05(tmp_path_factory.mktemp("tiny_pi05"))


@pytest.fixture
def load(tiny_pi05):
    """Build the controller (by default on the tiny checkpoint and tokenizer) with the tiny sizes in place."""
    from sb3_memret.controllers.lerobot_pi05 import LeRobotPi05Controller

    def build(checkpoint: Path | None = None, **kwargs) -> LeRobotPi05Controller:
        kwargs.setdefault("tokenizer", tiny_pi05 / "tokenizer")
        kwargs.setdefault("prompt_template", TEMPLATE)
        with tiny_sizes():
            return LeRobotPi05Controller(checkpoint or tiny_pi05 / "checkpoint", **kwargs)

    return build


def fake_obs(batch: int = 2) -> dict:
    rng = np.random.default_rng(0)
    return {
        "agent": {"eef_state": rng.uniform(-1, 1, size=(batch, 8)).astype(np.float32)},
        "sensor_data": {cam: {"rgb": rng.integers(0, 256, (batch, 224, 224, 3), dtype=np.uint8)}
                        for cam in ("base_camera", "hand_camera")},
    }


def test_tiny_pi05_with_adapter_acts_end_to_end(tiny_pi05, load):
    controller = load(adapter=tiny_pi05 / "adapter")
    assert controller.spec.chunk_len == 10 and controller.spec.needs_images
    controller.reset([0, 1])
    first = controller.act(fake_obs(), PROMPTS)
    assert first.shape == (2, 10, 7) and first.dtype == np.float32 and np.isfinite(first).all()
    controller.reset([0, 1])
    np.testing.assert_array_equal(controller.act(fake_obs(), PROMPTS), first)  # seeded per env
    base = load()
    base.reset([0, 1])
    assert not np.allclose(base.act(fake_obs(), PROMPTS), first)  # the adapter is in effect


def test_tiny_pi05_acts_on_rendered_camera_images(load, rgb_task_env):
    """A few decisions on the real task with both cameras rendered on the CPU; the images matter."""
    from sb3_memret.physics.chunks import execute_chunk

    controller = load()
    obs, _ = rgb_task_env.reset(seed=3, options={"target_layer": 2})
    controller.reset([3])
    for _ in range(3):
        chunk = controller.act(obs, [PROMPTS[0]])[0]
        assert chunk.shape == (10, 7) and np.isfinite(chunk).all()
        outcome = execute_chunk(rgb_task_env, np.clip(chunk[:8], -1, 1))
        obs = outcome.obs
    assert outcome.steps == 8 and obs["sensor_data"]["base_camera"]["rgb"].shape == (1, 224, 224, 3)
    dark = {**obs, "sensor_data": {cam: {"rgb": torch.zeros_like(v["rgb"])} for cam, v in obs["sensor_data"].items()}}
    controller.reset([3])
    seen = controller.act(obs, [PROMPTS[0]])
    controller.reset([3])
    assert not np.allclose(controller.act(dark, [PROMPTS[0]]), seen)


def test_missing_images_are_refused(load):
    controller = load()
    controller.reset([0, 1])
    obs = fake_obs()
    del obs["sensor_data"]["base_camera"]
    with pytest.raises(ValueError, match=r"no base_camera image.*observation\.images\.image.*render_backend"):
        controller.act(obs, PROMPTS)


def test_drifted_prompt_is_refused(load):
    controller = load()
    controller.reset([0, 1])
    with pytest.raises(ValueError, match="matches no trained template"):
        controller.act(fake_obs(), ["pick out the cube. the cube sits in drawer layer 2.", PROMPTS[1]])


def copy_with(src: Path, dst: Path, file: str, edit) -> Path:
    """A copy of folder ``src`` whose safetensors ``file`` went through ``edit``."""
    from safetensors.torch import load_file, save_file

    shutil.copytree(src, dst)
    save_file(edit(load_file(dst / file)), dst / file)
    return dst


def test_checkpoint_missing_a_weight_raises(tiny_pi05, load, tmp_path):
    key = "model.action_out_proj.bias"
    checkpoint = copy_with(tiny_pi05 / "checkpoint", tmp_path / "ckpt", "model.safetensors",
                           lambda t: {k: v for k, v in t.items() if k != key})
    with pytest.raises(WeightsNotLoadedError, match=rf"1 missing: {key}"):
        load(checkpoint)


def test_checkpoint_without_weights_raises(tiny_pi05, load, tmp_path):
    checkpoint = shutil.copytree(tiny_pi05 / "checkpoint", tmp_path / "ckpt")
    (checkpoint / "model.safetensors").unlink()
    with pytest.raises(FileNotFoundError, match="has no model.safetensors"):
        load(checkpoint)


@pytest.mark.filterwarnings("ignore:Found missing adapter keys")  # peft's warning is what these turn into errors
@pytest.mark.parametrize("case", ["renamed", "dropped", "extra", "wrong_rank"])
def test_adapter_with_missing_or_mismatched_tensors_raises(tiny_pi05, load, tmp_path, case):
    def edit(tensors: dict) -> dict:
        if case == "renamed":  # saved under another wrapping: peft would skip them all
            return {k.replace("base_model.model.model.", "base_model.model."): v for k, v in tensors.items()}
        if case == "dropped":
            return {k: v for k, v in tensors.items() if "action_out_proj.lora_B" not in k}
        if case == "extra":
            return {**tensors, "base_model.model.model.time_mlp_in.lora_A.weight": torch.ones(4, TINY_WIDTH)}
        key = next(k for k in tensors if k.endswith("lora_A.weight"))
        return {**tensors, key: torch.zeros(5, tensors[key].shape[1])}

    adapter = copy_with(tiny_pi05 / "adapter", tmp_path / "adapter", "adapter_model.safetensors", edit)
    expected = {"renamed": "12 missing.*12 unexpected", "dropped": "1 missing: .*action_out_proj.lora_B",
                "extra": "1 unexpected: .*time_mlp_in", "wrong_rank": "does not fit the policy.*size mismatch"}[case]
    with pytest.raises(WeightsNotLoadedError, match=rf"(?s)LoRA adapter .*{expected}"):
        load(adapter=adapter)

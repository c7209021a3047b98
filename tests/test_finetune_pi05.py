"""finetune_pi05: a LoRA adapter for a tiny random PI05 trained on a tiny demonstration dataset on the CPU,
loaded back by LeRobotPi05Controller with the project's 19-D state."""

from __future__ import annotations

import filecmp
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from sb3_memret.controllers.observation import ACTION_KEY, STATE_KEY, dataset_features
from sb3_memret.tasks.drawer.prompts import TEMPLATE
from tiny_pi05 import TINY_CHUNK, build_tiny_pi05, tiny_sizes

PROMPT = "pick out the cube. the cube is in drawer layer 2."
STEPS = 3


def make_dataset(root: Path, features: dict, episodes: tuple[int, ...] = (12, 9), task: str = PROMPT) -> Path:
    """A LeRobotDataset of random frames written with lerobot's recording API, as ``sb3-memret demos`` does."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset.create(repo_id="local/tiny", fps=20, features=features, root=root, use_videos=False,
                                    video_backend="pyav")  # PNG images: no video decoder to probe
    rng = np.random.default_rng(0)
    for length in episodes:
        for _ in range(length):
            frame = {key: rng.integers(0, 256, spec["shape"], dtype=np.uint8) if spec["dtype"] == "image"
                     else rng.normal(size=spec["shape"]).astype(np.float32) for key, spec in features.items()}
            dataset.add_frame({**frame, "task": task})
        dataset.save_episode()
    dataset.finalize()
    return root


@pytest.fixture(scope="module")
def tiny_pi05(tmp_path_factory):
    """The tiny random PI05 checkpoint (8-D LIBERO state) and its tokenizer (``tiny_pi05.py``)."""
    return build_tiny_pi05(tmp_path_factory.mktemp("tiny_pi05"))


@pytest.fixture(scope="module")
def finetuned(tiny_pi05, tmp_path_factory):
    """One finetuning run, with the peft-wrapped policy and its parameters as wrapped (before training)."""
    import peft

    from sb3_memret.stage1.finetune_pi05 import finetune_pi05

    root = tmp_path_factory.mktemp("finetune_pi05")
    dataset = make_dataset(root / "data", dataset_features(with_images=True))
    wrapped, losses = {}, []
    get_peft_model = peft.get_peft_model

    def spy(model, config, *args, **kwargs):
        wrapped["model"] = get_peft_model(model, config, *args, **kwargs)
        wrapped["initial"] = {n: p.detach().clone() for n, p in wrapped["model"].named_parameters()}
        return wrapped["model"]

    with tiny_sizes(), pytest.MonkeyPatch.context() as mp:
        mp.setattr(peft, "get_peft_model", spy)
        out = finetune_pi05(dataset, tiny_pi05 / "checkpoint", root / "out", steps=STEPS, batch_size=2,
                            learning_rate=1e-3, lora_rank=4, device="cpu", tokenizer=tiny_pi05 / "tokenizer",
                            on_step=lambda step, loss: losses.append((step, loss)), num_workers=0,
                            prompt_template=TEMPLATE)
    return dict(out=out, dataset=dataset, losses=losses, **wrapped)


def test_finetuning_trains_only_the_lora_factors(finetuned, tiny_pi05):
    assert finetuned["out"].name == "out"
    assert [step for step, _ in finetuned["losses"]] == list(range(1, STEPS + 1))
    assert all(math.isfinite(loss) for _, loss in finetuned["losses"])
    log = (finetuned["out"] / "train_log.csv").read_text().splitlines()
    assert log[0] == "step,loss" and len(log) == STEPS + 1
    lora, base = [], []
    for name, param in finetuned["model"].named_parameters():
        (lora if "lora_" in name else base).append(not torch.equal(param, finetuned["initial"][name]))
    assert lora and all(lora)  # every LoRA factor moved
    assert base and not any(base)  # no pretrained weight did
    assert filecmp.cmp(finetuned["out"] / "checkpoint/model.safetensors", tiny_pi05 / "checkpoint/model.safetensors",
                       shallow=False)


def fake_obs(batch: int = 2, opening: float = 0.0) -> dict:
    """A DrawerCubeTakeOut-v1-like observation with the 19-D state's parts and both cameras."""
    rng = np.random.default_rng(0)
    return {
        "agent": {"eef_state": rng.uniform(-1, 1, (batch, 8)).astype(np.float32)},
        "extra": {"drawer_opening": np.full((batch, 3), opening, dtype=np.float32),
                  "target_detection": rng.uniform(-1, 1, (batch, 8)).astype(np.float32)},
        "sensor_data": {cam: {"rgb": rng.integers(0, 256, (batch, 224, 224, 3), dtype=np.uint8)}
                        for cam in ("base_camera", "hand_camera")},
    }


def test_finetuned_pi05_loads_in_the_controller_and_acts_on_the_19d_state(finetuned, tiny_pi05):
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata

    from sb3_memret.controllers.lerobot_pi05 import LeRobotPi05Controller

    out = finetuned["out"]
    with tiny_sizes():  # strict checks of every weight and adapter tensor
        controller = LeRobotPi05Controller(out / "checkpoint", adapter=out / "adapter",
                                           tokenizer=tiny_pi05 / "tokenizer", prompt_template=TEMPLATE)
    stats = LeRobotDatasetMetadata("local/tiny", root=finetuned["dataset"]).stats
    normalizer = next(step for step in controller.preprocess.steps if type(step).__name__ == "NormalizerProcessorStep")
    for key in (STATE_KEY, ACTION_KEY):
        np.testing.assert_allclose(np.asarray(normalizer.stats[key]["q01"]), stats[key]["q01"])
    controller.reset([0, 1])
    chunks = controller.act(fake_obs(), [PROMPT, "pick out the cube."])
    assert chunks.shape == (2, TINY_CHUNK, 7) and chunks.dtype == np.float32 and np.isfinite(chunks).all()
    controller.reset([0, 1])
    opened = controller.act(fake_obs(opening=0.3), [PROMPT, "pick out the cube."])
    assert not np.allclose(opened, chunks)  # the drawer openings (state 9..11) reach the policy


@pytest.mark.parametrize("case", ["action", "state", "cameras", "task"])
def test_a_dataset_that_does_not_fit_is_refused(tiny_pi05, tmp_path, case):
    from sb3_memret.stage1.finetune_pi05 import finetune_pi05

    features = dataset_features(with_images=True)
    if case == "action":
        features[ACTION_KEY] = {**features[ACTION_KEY], "shape": (6,), "names": list("abcdef")}
    elif case == "state":
        features[STATE_KEY] = {**features[STATE_KEY], "shape": (12,), "names": [f"s{i}" for i in range(12)]}
    elif case == "cameras":
        del features["observation.images.wrist_image"]
    task = "pick out the cube. the cube sits in drawer layer 2." if case == "task" else PROMPT
    dataset = make_dataset(tmp_path / "data", features, episodes=(3,), task=task)
    expected = {"action": r"has action .*shape=\(6,\).*takes \(7,\) actions",
                "state": r"has observation\.state .*shape=\(12,\).*\(8,\) eef_state or the project's \(19,\)",
                "cameras": r"\(to finetune PI05 .*checkpoint\) has image features \['observation\.images\.image'\], "
                           r"but .*wrist_image",
                "task": r"has a task outside the prompt contract"}[case]
    with pytest.raises(ValueError, match=rf"dataset {dataset} .*{expected}"):
        finetune_pi05(dataset, tiny_pi05 / "checkpoint", tmp_path / "out", steps=1, batch_size=1, learning_rate=1e-3,
                      lora_rank=4, device="cpu", tokenizer=tiny_pi05 / "tokenizer", num_workers=0,
                      prompt_template=TEMPLATE)
    assert not (tmp_path / "out").exists()

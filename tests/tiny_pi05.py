"""A tiny randomly initialised PI05 checkpoint (with processors, a LoRA adapter and a local tokenizer),
built in seconds on a CPU, for the tests of the lerobot controller and of PI05 finetuning."""

from __future__ import annotations

import contextlib
import functools
from pathlib import Path

import pytest
import torch
from torch import nn

TINY_WIDTH = 64
TINY_VISION = dict(model_type="siglip_vision_model", hidden_size=32, intermediate_size=64, num_hidden_layers=1,
                   num_attention_heads=2, patch_size=56, vision_use_head=False)
TINY_CHUNK = 10


class TinyProjector(nn.Module):
    """PaliGemma's image projector, onto the (tiny) language width instead of lerobot's fixed 2048."""

    def __init__(self, config):
        super().__init__()
        self.linear = nn.Linear(config.vision_config.hidden_size, config.text_config.hidden_size)

    def forward(self, image_features: torch.Tensor) -> torch.Tensor:
        return self.linear(image_features)


@contextlib.contextmanager
def tiny_sizes():
    """Shrink PI05 where lerobot reads its fixed sizes (gemma_300m/2b, the So400m vision tower, a
    2048-wide image projector), for building and loading alike."""
    from transformers import GemmaConfig, PaliGemmaConfig
    from transformers.models.paligemma import modeling_paligemma

    from lerobot.policies.pi05 import modeling_pi05

    # 8 heads: lerobot's training forward (compute_layer_complete) hardcodes PaliGemma's 8 attention heads.
    gemma = modeling_pi05.GemmaConfig(width=TINY_WIDTH, depth=2, mlp_dim=128, num_heads=8, num_kv_heads=1,
                                      head_dim=TINY_WIDTH // 8)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(modeling_pi05, "get_gemma_config", lambda variant: gemma)
        mp.setattr(modeling_pi05, "CONFIG_MAPPING",
                   {"paligemma": functools.partial(PaliGemmaConfig, vision_config=TINY_VISION), "gemma": GemmaConfig})
        mp.setattr(modeling_paligemma, "PaliGemmaMultiModalProjector", TinyProjector)
        yield


def build_tiny_pi05(root: Path) -> Path:
    """Write ``root``/checkpoint (a random PI05, ~50 M parameters, mostly the 257k-token embeddings, on
    LIBERO's cameras and 8-D state, with its processors), ``root``/adapter (a random LoRA adapter) and
    ``root``/tokenizer; returns ``root``."""
    import peft
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.policies.pi05 import PI05Config, PI05Policy
    from lerobot.policies.pi05.processor_pi05 import make_pi05_pre_post_processors
    from lerobot.processor import tokenizer_processor

    tokenizer = make_tokenizer(root / "tokenizer")
    feature = lambda kind, shape: PolicyFeature(type=kind, shape=shape)  # noqa: E731
    config = PI05Config(
        device="cpu", chunk_size=TINY_CHUNK, n_action_steps=TINY_CHUNK, num_inference_steps=2,
        input_features={"observation.images.image": feature(FeatureType.VISUAL, (3, 224, 224)),
                        "observation.images.wrist_image": feature(FeatureType.VISUAL, (3, 224, 224)),
                        "observation.state": feature(FeatureType.STATE, (8,))},
        output_features={"action": feature(FeatureType.ACTION, (7,))},
    )
    with tiny_sizes(), pytest.MonkeyPatch.context() as hub:
        torch.manual_seed(0)
        policy = PI05Policy(config)
        policy.save_pretrained(root / "checkpoint")
        stats = {key: {"q01": -torch.ones(n), "q99": torch.ones(n)}
                 for key, n in (("observation.state", 8), ("action", 7))}
        hub.setattr(tokenizer_processor.AutoTokenizer, "from_pretrained", lambda name, **kw: tokenizer)  # not the hub's
        for pipeline in make_pi05_pre_post_processors(config, dataset_stats=stats):
            pipeline.save_pretrained(root / "checkpoint")
        lora = peft.LoraConfig(r=4, target_modules=policy._get_default_peft_targets()["target_modules"],
                               init_lora_weights=False)  # random B: the adapter changes the actions
        peft.get_peft_model(policy, lora).save_pretrained(root / "adapter")
    return root


def make_tokenizer(folder: Path):
    """A word-level tokenizer saved like a hub one, standing in for PaliGemma's gated tokenizer."""
    from tokenizers import Tokenizer, models, pre_tokenizers
    from transformers import PreTrainedTokenizerFast

    words = "Task: State: Action: pick out the cube. is in drawer layer".split() + [str(i) for i in range(256)]
    vocab = {w: i for i, w in enumerate(["<pad>", "<unk>", "<bos>", "<eos>", *dict.fromkeys(words)])}
    model = Tokenizer(models.WordLevel(vocab, unk_token="<unk>"))
    model.pre_tokenizer = pre_tokenizers.WhitespaceSplit()
    tokenizer = PreTrainedTokenizerFast(tokenizer_object=model, pad_token="<pad>", unk_token="<unk>",
                                        bos_token="<bos>", eos_token="<eos>")
    tokenizer.save_pretrained(folder)
    return tokenizer

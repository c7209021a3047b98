import numpy as np
import pytest

from sb3_memret.memory.encoder import EMBEDDING_DIM, MiniLMEncoder


def test_unit_norm_384(encoder):
    v = encoder.encode(["the cube is in drawer layer 2.", "pick out the cube."])
    assert v.shape == (2, EMBEDDING_DIM) and v.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5)


def test_deterministic_and_semantic(encoder):
    texts = ["the cube is in drawer layer 1.", "the cube is in drawer layer 3.", "the robot is holding the mug."]
    fresh = MiniLMEncoder().encode(texts)
    np.testing.assert_allclose(encoder.encode(texts), fresh, atol=1e-6)
    # two cube locations are closer to each other than to a holding fact
    assert fresh[0] @ fresh[1] > fresh[0] @ fresh[2]


def test_cache_hits_on_repeats(encoder):
    text = "the key is in drawer layer 2."
    encoder.encode([text])
    hits, misses = encoder.hits, encoder.misses
    out = encoder.encode([text, text, text])
    assert encoder.misses == misses and encoder.hits == hits + 3
    np.testing.assert_array_equal(out[0], out[2])
    assert encoder.encode([]).shape == (0, EMBEDDING_DIM)


def test_missing_model_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no sentence-transformers model at"):
        MiniLMEncoder(tmp_path)

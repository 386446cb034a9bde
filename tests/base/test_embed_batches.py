"""`embed.same_batches`: a list of texts embedded again gets the model's own vectors without the model."""

from __future__ import annotations

import numpy as np


def test_same_batches_gives_a_repeated_batch_the_models_own_vectors_without_the_model():
    """A noise sweep's three banks of one cell embed the same segment texts (bench/noise.py): inside
    `same_batches` the second list is not embedded again, and gets bit for bit what a fresh
    process's model gives it."""
    from memora_graph.embed import clear_embedding_caches, get_embedder, same_batches

    emb = get_embedder()
    texts = ["take the knife from the drawer", "wash the pan", "open the fridge and take the milk"]
    clear_embedding_caches()
    fresh = emb.encode(texts)
    with same_batches() as counted:
        clear_embedding_caches()
        first = emb.encode(texts)
        clear_embedding_caches()
        encoded = emb.encoded
        again = emb.encode(texts)
        assert emb.encoded == encoded, "the model was asked again"
        clear_embedding_caches()
        other = emb.encode(texts[::-1])  # another list (another batch): the model's
    assert (counted.embedded, counted.spared, len(counted.vectors)) == (6, 3, 2)
    assert np.array_equal(fresh, first) and np.array_equal(first, again)
    assert np.allclose(other[::-1], fresh, atol=1e-6)
    clear_embedding_caches()
    assert np.array_equal(emb.encode(texts), fresh)  # outside the block: the model again

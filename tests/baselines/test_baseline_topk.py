"""The baselines' top-k with near-duplicate collapse is checked a block at a time; it must return
what the pair-by-pair definition returns, row for row (the evaluation's records depend on it)."""

from __future__ import annotations

import numpy as np
import pytest

from memora_graph.baselines.common import reference_top_k, top_k


@pytest.mark.parametrize("seed", range(6))
def test_block_top_k_equals_the_pairwise_definition(seed):
    rng = np.random.default_rng(seed)
    for _ in range(25):
        n, d = int(rng.integers(1, 1500)), 24
        base = rng.normal(size=(max(1, n // 25), d)).astype(np.float32)  # many near-copies, as a raw bank has
        noise = float(rng.choice([0.0, 0.005, 0.03, 0.2]))
        m = base[rng.integers(0, len(base), n)] + rng.normal(scale=noise, size=(n, d)).astype(np.float32)
        m /= np.linalg.norm(m, axis=1, keepdims=True)
        q = (m[rng.integers(0, n)] + rng.normal(scale=0.1, size=d)).astype(np.float32)
        mask = rng.random(n) < 0.4 if rng.random() < 0.3 else None
        k, dedup = int(rng.integers(1, 31)), float(rng.choice([0.95, 0.9, 0.999]))
        assert top_k(m, q, k, mask, dedup) == reference_top_k(m, q, k, mask, dedup)


def test_threshold_ties_are_decided_as_the_pairwise_loop_decides_them():
    a = np.array([1.0, 0.0], np.float32)
    b = np.array([0.95, np.sqrt(1 - 0.95 ** 2)], np.float32)  # cosine with a: 0.95 up to float rounding
    m = np.stack([a, b, b, a])
    q = np.array([1.0, 0.1], np.float32)
    for dedup in (0.95, float(a @ b), float(np.nextafter(a @ b, 1.0))):
        assert top_k(m, q, 3, dedup=dedup) == reference_top_k(m, q, 3, dedup=dedup)
    assert top_k(np.zeros((0, 2), np.float32), q, 3) == []

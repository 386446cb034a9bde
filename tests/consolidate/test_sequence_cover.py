"""Action sequences covered by a longer one are dropped in consolidation; the per-candidate index
of parts must decide exactly as comparing every pair of candidates did."""

from __future__ import annotations

import random

from memora_graph.consolidate.rules import _longest_cover, _longest_cover_pairwise


def test_cover_index_equals_the_pairwise_definition():
    rng = random.Random(7)
    tokens = ["take plate", "wash plate", "put plate rack", "open tap", "close tap", "take sponge"]
    for _ in range(200):
        cands = {tuple(rng.choice(tokens) for _ in range(rng.randint(1, 5))): rng.randint(1, 9)
                 for _ in range(rng.randint(1, 40))}
        fast, slow = _longest_cover(cands), _longest_cover_pairwise(cands)
        assert {k: fast[k] for k in cands if k in fast} == slow


def test_cover_worked_example():
    cands = {("a", "b"): 3, ("a", "b", "c"): 2, ("x", "a", "b", "c"): 4, ("c",): 5}
    cover = _longest_cover(cands)
    assert cover[("a", "b")] == 4 and cover[("a", "b", "c")] == 4 and cover[("c",)] == 4
    assert ("x", "a", "b", "c") not in cover

"""Fixtures for the MEMORA-Bench tests: a small real cohort from the bundled annotations."""

from __future__ import annotations

import pytest

COHORT = ["P01", "P09", "P23", "P37"]  # one rich participant, the two smallest, one with 2 videos


@pytest.fixture(scope="session")
def cohort_annotations():
    from memora_graph.perceive.annotations import load_annotations

    return load_annotations(participants=COHORT)


@pytest.fixture(scope="session")
def behaviours(cohort_annotations):
    from memora_graph.bench.behaviour import build_behaviours

    return build_behaviours(cohort_annotations)


@pytest.fixture(scope="session")
def generated(cohort_annotations):
    """The cohort's suite with seed 1, without the embedding check (exact dedup only)."""
    from memora_graph.bench.generate import generate_suite

    return generate_suite(cohort_annotations, seed=1, embedder=None)

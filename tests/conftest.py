"""Shared fixtures: real Kùzu in temporary directories, the bundled MiniLM, small real banks."""

from __future__ import annotations

import pytest

from memora_graph.paths import epic_dir


@pytest.fixture(scope="session")
def embedder():
    from memora_graph.embed import get_embedder

    return get_embedder()


@pytest.fixture(scope="session")
def epic_meta():
    from memora_graph.perceive.annotations import load_class_tables, load_video_info

    return load_class_tables(epic_dir()), dict(load_video_info(epic_dir()).select("video_id", "duration").iter_rows())


@pytest.fixture(scope="session")
def small_bank(tmp_path_factory, embedder):
    """P09 and P37 built from the bundled annotations (the two smallest participants)."""
    from memora_graph.pipeline import build_bank

    path = tmp_path_factory.mktemp("bank") / "small"
    result = build_bank(path, ["P09", "P37"])
    return path, result


@pytest.fixture(scope="session")
def ray_local():
    """A local Ray instance with 2 CPUs for the `ray` tests (skipped, saying so, without the extra)."""
    ray = pytest.importorskip("ray", reason="Ray is not installed: pip install -e '.[dev,ray]' (the [ray] extra)")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def pytest_collection_modifyitems(config, items):
    """Tests marked `slow` run only when asked for (`-m slow`)."""
    if "slow" in (config.getoption("markexpr") or ""):
        return
    skip = pytest.mark.skip(reason="slow: run with `-m slow`")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)

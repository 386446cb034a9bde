"""The build's torch thread choice: every core on an idle machine, one while other processes are busy."""

from __future__ import annotations

import numpy as np
import pytest

from memora_graph import embed
from memora_graph.embed import ThreadGovernor, adaptive_threads


class _Clock:
    """A fake /proc/stat: the machine's busy CPU-seconds, ours, and the time."""

    def __init__(self):
        self.busy = self.own = self.wall = 0.0

    def advance(self, seconds: float, own_cores: float, other_cores: float) -> None:
        self.wall += seconds
        self.own += seconds * own_cores
        self.busy += seconds * (own_cores + other_cores)

    def sample(self):
        return self.busy, self.own, self.wall


@pytest.fixture()
def clock(monkeypatch):
    c = _Clock()
    monkeypatch.setattr(embed, "_cpu_sample", c.sample)
    return c


def test_governor_uses_every_core_only_while_others_are_idle(clock):
    g = ThreadGovernor(max_threads=2)
    clock.advance(1.0, own_cores=2.0, other_cores=0.0)
    assert g() == 2
    clock.advance(1.0, own_cores=1.0, other_cores=1.0)  # another process took a core
    assert g() == 1
    clock.advance(0.05, own_cores=1.0, other_cores=0.0)  # too short a window to change its mind
    assert g() == 1
    clock.advance(1.0, own_cores=1.0, other_cores=0.1)  # background noise only
    assert g() == 2
    assert g.calls == {2: 2, 1: 2}


def test_governor_without_proc_stat_stays_on_one_thread(monkeypatch):
    monkeypatch.setattr(embed, "_cpu_sample", lambda: None)
    g = ThreadGovernor(max_threads=2)
    assert g() == 1 and g() == 1


def test_adaptive_threads_sets_and_restores_torch_threads(clock, embedder):
    import torch

    before = torch.get_num_threads()
    clock.advance(1.0, own_cores=1.0, other_cores=1.0)
    with adaptive_threads(embedder, ThreadGovernor(max_threads=2)) as g:
        clock.advance(1.0, own_cores=1.0, other_cores=1.0)
        vecs = embedder.inner.encode(["a knife on the counter"])
        assert g.calls == {1: 1} and torch.get_num_threads() == 1
    assert embedder.inner.threads is None and torch.get_num_threads() == before
    assert np.allclose(vecs, embedder.inner.encode(["a knife on the counter"]), atol=1e-5)

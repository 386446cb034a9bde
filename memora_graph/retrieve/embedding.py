"""Query embeddings for the tools: one LRU cache per process, encoded on one thread.

Queries go through the embedder's query encoder (memora_graph/embed.py: ONNX Runtime on one
thread by default, no torch). Where that is PyTorch: on the 2-core machines this project
targets, torch's default of one intra-op thread per core makes a MiniLM forward pass ~2x slower
(batch) to ~25x slower (one short query) than a single thread, because the two threads spin
against each other and against Kùzu. `torch_threads(1)` scopes the setting to the encode call
and restores it after.
"""

from __future__ import annotations

from collections import OrderedDict
from contextlib import contextmanager

import numpy as np

from memora_graph.embed import uses_torch


@contextmanager
def torch_threads(n: int = 1, embedder=None, kind: str = "query"):
    """Torch on `n` intra-op threads within the block; with `embedder`, only where it encodes
    `kind` texts with torch (torch is then never imported for an ONNX query encoder)."""
    if embedder is not None and not uses_torch(embedder, kind):
        yield
        return
    try:
        import torch
    except ImportError:  # an embedder without torch: nothing to scope
        yield
        return
    before = torch.get_num_threads()
    if before != n:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if before != n:
            torch.set_num_threads(before)


def encode_passages(embedder, texts: list[str], batch_size: int = 32) -> np.ndarray:
    """Batch passage encoding on one torch thread, in batches of at most 32 (on these CPUs a batch
    of 128 short texts is ~1.2x slower per text than 32; see memora_graph/embed.py)."""
    inner = getattr(embedder, "inner", embedder)
    before = getattr(inner, "batch_size", None)
    if before is not None:
        inner.batch_size = min(before, batch_size)
    try:
        with torch_threads(1, embedder, "passage"):
            return embedder.encode(texts, kind="passage")
    finally:
        if before is not None:
            inner.batch_size = before


class QueryEncoder:
    """Embeds tool queries; repeats (an agent re-asking, `search` fanning out) hit the cache."""

    def __init__(self, embedder, size: int = 4096):
        self.embedder = embedder
        self.size = size
        self._cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self.hits = self.misses = 0

    def __call__(self, text: str) -> np.ndarray:
        v = self._cache.get(text)
        if v is not None:
            self._cache.move_to_end(text)
            self.hits += 1
            return v
        self.misses += 1
        # through the embedder's own cache when it has one (the process-wide CachedEmbedder): a
        # query asked of several memories (the seven bench conditions) or warmed by `prefetch`
        # is encoded once
        with torch_threads(1, self.embedder):
            v = np.asarray(self.embedder.encode([text], kind="query")[0], dtype=np.float32)
        self._cache[text] = v
        if len(self._cache) > self.size:
            self._cache.popitem(last=False)
        return v

    def prefetch(self, texts: list[str]) -> None:
        """Encode the texts not yet cached in one batch (an agent response carrying several calls
        costs about one forward pass instead of one per call)."""
        stripped = (t.strip() for t in texts if isinstance(t, str))  # the tools strip their queries too
        todo = list(dict.fromkeys(t for t in stripped if t and t not in self._cache))
        if not todo:
            return
        with torch_threads(1, self.embedder):
            vecs = np.asarray(self.embedder.encode(todo, kind="query"), dtype=np.float32)
        for t, v in zip(todo, vecs):
            self._cache[t] = v
        while len(self._cache) > self.size:
            self._cache.popitem(last=False)

    def clear(self, everywhere: bool = False) -> None:
        """Forget the cached query vectors; `everywhere`: the embedder's process-wide cache too, so
        that the next call embeds its query (a benchmark's cold call)."""
        self._cache.clear()
        if everywhere and hasattr(self.embedder, "clear"):
            self.embedder.clear()

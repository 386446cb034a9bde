"""Query embeddings for the tools: one LRU cache per process, encoded on one thread.

Queries go through the embedder's query encoder (memora_graph/embed.py: ONNX Runtime on one
thread by default, no torch). Where that is PyTorch: on the 2-core machines this project
targets, torch's default of one intra-op thread per core makes a MiniLM forward pass ~2x slower
(batch) to ~25x slower (one short query) than a single thread, because the two threads spin
against each other and against Kùzu. `torch_threads(1)` (memora_graph/embed.py) scopes the setting to
the encode call and restores it after.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from memora_graph.embed import torch_threads


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

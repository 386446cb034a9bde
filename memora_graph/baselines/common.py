"""What the baseline memories share: reading a participant's bank records, an on-disk embedding
store (a text is embedded once per bank, whichever representation needs it), and cosine top-k
with the paper's near-duplicate collapse (cosine >= 0.95 keeps the higher-scoring record).

Representations are cached under `BANK/.cache/`, keyed by the participant's manifest entry, so
a rebuilt participant invalidates its cache and nothing else. Each cache file's sha256 is recorded
in the manifest (bank/derived.py: `baseline-<name>` of the participant, the embedding cache
bank-wide): a file not as recorded is built again, never read.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from memora_graph.bank import MANIFEST, Bank
from memora_graph.bank.derived import recorded, sha256_bytes, sha256_file
from memora_graph.errors import BankError
from memora_graph.embed import get_embedder, single_thread_blas, torch_threads

CACHE_DIR = ".cache"
log = logging.getLogger("memora_graph.integrity")
M = TypeVar("M")  # a baseline memory
DEDUP_COSINE = 0.95
DEFAULT_TOP_K = 10
MAX_TOP_K = 30


def clamp_top_k(value: Any, default: int = DEFAULT_TOP_K) -> int:
    try:
        k = int(value)
    except (TypeError, ValueError):
        k = default
    return max(1, min(MAX_TOP_K, k))


def cache_dir(bank: Bank) -> Path:
    path = bank.path / CACHE_DIR
    path.mkdir(parents=True, exist_ok=True)
    return path


def participant_key(bank: Bank, participant: str, version: str) -> str:
    """Changes whenever the participant is rebuilt (its manifest entry) or the code version moves."""
    entry = {k: v for k, v in bank.manifest()["participants"][participant].items() if k != "derived"}
    blob = json.dumps({"entry": entry, "mode": bank.manifest().get("mode"), "v": version}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def cache_or_build(bank_path: str | Path, participant: str, name: str, version: str, *,
                   read: Callable[[str, Any, np.ndarray], M], build: Callable[[dict[str, list[dict]], str], tuple[Any, Any, list[str]]],
                   make: Callable[[str, Any, np.ndarray], M], store: EmbeddingStore | None = None,
                   damaged: tuple[type[Exception], ...] = ()) -> M:
    """A participant's baseline memory `name`, read from `BANK/.cache/` when cached, else built once.
    Each callback gets the bank's mode first (its records are 'edited' or 'raw').

    Cached: `read(mode, json data, vectors)` makes it from the two files; a file that cannot be
    read or parsed (OSError, ValueError, KeyError, TypeError, or one of `damaged`) is rebuilt from
    the bank, never trusted. Not cached: `build(the participant's bank records, mode)` gives (what
    it built, its JSON data, the texts to embed); the texts are encoded with `store` (default: the
    bank's), both files are written (the JSON last: a cache is complete when its JSON exists), and
    `make(mode, what it built, vectors)`."""
    single_thread_blas()  # as MEMORA's view: a query against a few thousand rows is 2-3x slower on BLAS threads
    bank = Bank(bank_path)
    mode = bank.manifest().get("mode", "edited")
    key = participant_key(bank, participant, version)
    base = cache_dir(bank) / f"{name}-{participant}-{key}"
    path, npy = base.with_suffix(".json"), base.with_suffix(".npy")
    record_name = f"baseline-{name}"
    if path.exists() and npy.exists():
        try:
            raw, npy_raw = path.read_bytes(), npy.read_bytes()
            if recorded(bank.derived.get(participant, record_name), key, {path.name: raw, npy.name: npy_raw}):
                return read(mode, json.loads(raw), np.load(io.BytesIO(npy_raw), allow_pickle=False))
            log.warning(f"{base}.json/.npy: not as recorded in {MANIFEST} (edited, damaged, or written before "
                        "caches were recorded there); built again from the bank")
        except (OSError, ValueError, KeyError, TypeError, *damaged):
            pass
    built, data, texts = build(load_records(bank, participant), mode)
    store = store or EmbeddingStore(bank)
    vectors = store.encode(texts)
    store.save()
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    text = json.dumps(data)
    tmp.write_text(text)
    np.save(npy, vectors)
    os.replace(tmp, path)
    try:  # the files are trusted by a later read only as recorded in the manifest (bank/derived.py)
        bank.derived.put(participant, record_name, {"of": key, "files": {
            path.name: sha256_bytes(text.encode()), npy.name: sha256_file(npy)}})
    except (OSError, BankError) as exc:
        log.warning(f"{bank.path}: could not record {base.name} in {MANIFEST} ({exc}); it is built again next time")
    return make(mode, built, vectors)


# whole-participant reads: the public queries of these give a video at a time (issue 36)
_WHOLE = {"segments": "_baseline_segments_all", "state_events": "_baseline_state_events_all"}


def load_records(bank: Bank, participant: str) -> dict[str, list[dict]]:
    """The participant's records through the named baseline queries (one read-only open)."""
    with bank.open(participant) as store:
        return {
            name: store.rows(_WHOLE.get(name, f"baseline_{name}"), participant=participant)
            for name in ("segments", "state_events", "entities", "places", "routines", "preferences")
        }


class EmbeddingStore:
    """text -> vector, persisted per bank and model in `BANK/.cache/embeddings-<model>.npz`."""

    def __init__(self, bank: Bank, model: str | None = None):
        self.embedder = get_embedder(model)
        safe = re.sub(r"[^A-Za-z0-9._-]+", "_", self.embedder.name)
        self.bank = bank
        self.path = cache_dir(bank) / f"embeddings-{safe}.npz"
        self._vectors: dict[str, np.ndarray] = {}
        if self.path.exists():
            try:
                raw = self.path.read_bytes()
                if not recorded(bank.derived.get(None, self.path.name), self.path.name, {self.path.name: raw}):
                    raise ValueError(f"not as recorded in {MANIFEST}")
                with np.load(io.BytesIO(raw)) as data:
                    keys, mat = data["keys"], data["vectors"]
                self._vectors = {str(k): mat[i] for i, k in enumerate(keys)}
            except Exception as exc:  # a damaged or unrecorded cache is rebuilt, never trusted
                log.warning(f"{self.path}: {exc}; its texts are embedded again")
                self._vectors = {}
                self._dirty = True
        self._dirty = self.__dict__.get("_dirty", False)

    @staticmethod
    def _key(text: str) -> str:
        return hashlib.blake2b(text.encode(), digest_size=12).hexdigest()

    def encode(self, texts: list[str]) -> np.ndarray:
        keys = [self._key(t) for t in texts]
        todo = {}
        for k, t in zip(keys, texts):
            if k not in self._vectors and k not in todo:
                todo[k] = t
        if todo:
            vecs = self.embedder.encode(list(todo.values()), kind="passage")
            for k, v in zip(todo, vecs):
                self._vectors[k] = v
            self._dirty = True
        if not texts:
            return np.zeros((0, self.embedder.dim), dtype=np.float32)
        return np.stack([self._vectors[k] for k in keys]).astype(np.float32)

    def save(self) -> None:
        if not self._dirty:
            return
        keys = np.array(list(self._vectors))
        mat = np.stack(list(self._vectors.values())).astype(np.float32)
        tmp = self.path.with_name(f"{self.path.stem}.{os.getpid()}.tmp.npz")  # parallel bench workers share the bank
        np.savez(tmp, keys=keys, vectors=mat)
        digest = sha256_file(tmp)
        os.replace(tmp, self.path)
        self._dirty = False
        try:  # (two workers saving at once: the record may name the other's file, which is then embedded again)
            self.bank.derived.put(None, self.path.name, {"of": self.path.name, "files": {self.path.name: digest}})
        except (OSError, BankError) as exc:
            log.warning(f"{self.bank.path}: could not record {self.path.name} in {MANIFEST} ({exc})")


def embed_query(text: str, model: str | None = None) -> np.ndarray:
    return get_embedder(model).encode([text], kind="query")[0]


def prefetch_queries(texts: list[str]) -> None:
    """Embed the queries of one agent response in one batch (the tools then find them in the
    process-wide embedding cache)."""
    texts = list(dict.fromkeys(texts))
    if texts:
        embedder = get_embedder()
        with torch_threads(1, embedder):
            embedder.encode(texts, kind="query")


def _ranked(matrix: np.ndarray, query: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Each row's cosine to the query (-inf where `mask` is False) and the rows best first (stable)."""
    scores = matrix @ query
    if mask is not None:
        scores = np.where(mask, scores, -np.inf)
    return scores, np.argsort(-scores, kind="stable")


def top_k(matrix: np.ndarray, query: np.ndarray, k: int, mask: np.ndarray | None = None,
          dedup: float = DEDUP_COSINE) -> list[tuple[int, float]]:
    """(row, cosine) of the k best rows, best first, collapsing rows that are near-duplicates
    (cosine >= `dedup`) of a better-scoring row already taken.

    Candidates are checked a block at a time against the rows taken so far with one product per
    taken row, rather than one Python-level dot product per pair: a raw bank repeats the same
    fact at every sighting, and walking thousands of duplicates pair by pair cost Flat-1D ~0.2 s
    per item. A similarity within 1e-4 of the threshold is decided by the scalar product the
    pairwise loop used (`reference_top_k`), so the result is the same, row for row."""
    if matrix.shape[0] == 0:
        return []
    scores, order = _ranked(matrix, query, mask)
    finite = np.isfinite(scores[order])
    end = len(order) if finite.all() else int(np.argmin(finite))  # the first non-finite score stops the walk
    taken: list[int] = []
    pos = 0
    while len(taken) < k and pos < end:
        block = order[pos:min(pos + _BLOCK, end)]
        pos += len(block)
        rows = matrix[block]
        near = np.zeros(len(block), dtype=bool)
        for j in taken:
            near |= _at_least(rows, matrix, block, j, dedup)
        b = 0
        while b < len(block) and len(taken) < k:
            if not near[b]:
                i = int(block[b])
                taken.append(i)
                if b + 1 < len(block):
                    near[b + 1:] |= _at_least(rows[b + 1:], matrix, block[b + 1:], i, dedup)
            b += 1
    return [(i, round(float(scores[i]), 4)) for i in taken]


_BLOCK = 256
_BORDER = 1e-4


def _at_least(rows: np.ndarray, matrix: np.ndarray, idx: np.ndarray, j: int, dedup: float) -> np.ndarray:
    """cosine(row, matrix[j]) >= dedup for each row; borderline values by the scalar product."""
    sims = rows @ matrix[j]
    out = sims >= dedup
    for c in np.flatnonzero(np.abs(sims - dedup) < _BORDER):
        out[c] = float(matrix[idx[c]] @ matrix[j]) >= dedup
    return out


def reference_top_k(matrix: np.ndarray, query: np.ndarray, k: int, mask: np.ndarray | None = None,
                    dedup: float = DEDUP_COSINE) -> list[tuple[int, float]]:
    """`top_k` pair by pair, as it was first written: the definition the fast one is checked against."""
    if matrix.shape[0] == 0:
        return []
    scores, order = _ranked(matrix, query, mask)
    taken: list[int] = []
    for i in order:
        if not np.isfinite(scores[i]) or len(taken) >= k:
            break
        if any(float(matrix[i] @ matrix[j]) >= dedup for j in taken):
            continue
        taken.append(int(i))
    return [(i, round(float(scores[i]), 4)) for i in taken]


def place_name(location: str | None) -> str:
    return (location or "").replace("_", " ").strip()


def object_label(row: dict) -> str:
    parts = [row.get("color") or "", row.get("material") or "", row.get("name") or ""]
    return " ".join(p for p in parts if p).strip()

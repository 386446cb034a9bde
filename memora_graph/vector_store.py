"""Vectors of texts, each encoded alone, kept on disk between runs and shared between processes.

The offline reader compares each option with up to `MAX_TEXTS` evidence texts in meaning
(agent/reading.py), which makes the query encoder the largest cost of the offline evaluation:
on the calibration cohort the same few thousand narrations per participant come back in item
after item, in every condition, in both worker processes and in every run. `TextVectors`
encodes each distinct text once, ever, for a given encoder:

- **alone**, one text per encoder call, so its vector is a function of the text and the encoder,
  never of the other texts in a batch (ONNX Runtime's vectors differ in the last bits, up to
  ~7e-8, with the batch a text is in). A vector read back from disk is then bit for bit the one
  a fresh process would compute, and results do not depend on the cache, the worker split or
  the order items run in;
- **kept** in an SQLite file per encoder under the cache directory (`$MEMORA_CACHE_DIR`, see
  `onnx_embed.cache_root`), named by the encoder's identity (for ONNX the export's fingerprint
  and variant, for torch the model and library versions), so another model or export never
  reads these vectors. SQLite (standard library) gives concurrent readers and writers across
  the evaluation's worker processes without a lock of ours.

`MEMORA_VECTOR_CACHE=0` keeps the vectors in memory only. A damaged file is set aside with a
warning and a new one started; a cache directory that cannot be written leaves the vectors in
memory (with a note). Either way the vectors are the same.
"""

from __future__ import annotations

import hashlib
import logging
import os
import sqlite3
import threading
import time
from pathlib import Path

import numpy as np

log = logging.getLogger("memora_graph")

ENV = "MEMORA_VECTOR_CACHE"


def encoder_identity(encoder) -> str:
    """What the vectors depend on: for the ONNX query encoder its export (fingerprinted by the
    model files and ONNX Runtime's version) and variant; otherwise the model and torch's version."""
    directory, variant = getattr(encoder, "directory", None), getattr(encoder, "variant", None)
    if directory is not None and variant:
        return f"{Path(directory).name}-{variant}"
    try:
        import sentence_transformers
        import torch

        versions = f"torch{torch.__version__}-st{sentence_transformers.__version__}"
    except ImportError:
        versions = "unknown"
    name = str(getattr(encoder, "name", type(encoder).__name__))
    return f"{Path(name).name}-{hashlib.blake2b(name.encode(), digest_size=4).hexdigest()}-{versions}"


def _key(text: str) -> bytes:
    return hashlib.blake2b(text.encode(), digest_size=16).digest()


BUSY_TIMEOUT_S = 60.0  # how long a statement waits for another process's lock
OPEN_TRIES = 5  # a file locked while it is opened (another worker creating it) is tried again, then left alone


class _Disk:
    """The SQLite file: key (blake2b of the text) -> float32 bytes."""

    def __init__(self, path: Path, dim: int):
        self.path, self.dim = path, dim
        self._db = self._open()

    def _open(self) -> sqlite3.Connection:
        db = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT_S, isolation_level=None, check_same_thread=False)
        try:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA synchronous=NORMAL")
            db.execute("CREATE TABLE IF NOT EXISTS vectors (key BLOB PRIMARY KEY, vec BLOB NOT NULL) WITHOUT ROWID")
            db.execute("CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, value TEXT NOT NULL)")
            db.execute("INSERT OR IGNORE INTO meta VALUES ('dim', ?)", (str(self.dim),))
            (dim,) = db.execute("SELECT value FROM meta WHERE name = 'dim'").fetchone()
            if int(dim) != self.dim:
                raise sqlite3.DatabaseError(f"holds {dim}-d vectors, the encoder makes {self.dim}-d ones")
        except BaseException:
            db.close()
            raise
        return db

    def get(self, keys: list[bytes]) -> dict[bytes, np.ndarray]:
        out: dict[bytes, np.ndarray] = {}
        width = self.dim * 4
        for start in range(0, len(keys), 500):  # SQLite's bound-parameter limit
            chunk = keys[start:start + 500]
            rows = self._db.execute(f"SELECT key, vec FROM vectors WHERE key IN ({','.join('?' * len(chunk))})",
                                    chunk).fetchall()
            for k, v in rows:
                if len(v) != width:
                    raise sqlite3.DatabaseError(f"a vector of {len(v)} bytes, expected {width}")
                out[k] = np.frombuffer(v, dtype=np.float32).copy()
        return out

    def put(self, items: dict[bytes, np.ndarray]) -> None:
        self._db.executemany("INSERT OR IGNORE INTO vectors VALUES (?, ?)",
                             [(k, np.asarray(v, dtype=np.float32).tobytes()) for k, v in items.items()])

    def close(self) -> None:
        self._db.close()


class TextVectors:
    """`encode(texts)`: each text's vector from `encoder` (an Embedder: `encode(texts, kind)`),
    encoded alone, looked up in memory, then on disk, then computed and kept in both."""

    def __init__(self, encoder, kind: str = "query", root: Path | None = None, persist: bool | None = None):
        self.encoder, self.kind = encoder, kind
        self._memory: dict[bytes, np.ndarray] = {}
        self._disk: _Disk | None = None
        self._root, self._persist = root, persist
        self._opened = False
        self._lock = threading.Lock()  # one encode at a time (an MCP server's threads share a reader)
        self.encoded = 0  # texts this process encoded
        self.from_disk = 0  # texts read from the file
        self.seconds = 0.0  # spent encoding

    @property
    def path(self) -> Path | None:
        return self._disk.path if self._disk is not None else None

    def _open_disk(self) -> None:
        self._opened = True
        persist = self._persist if self._persist is not None else os.environ.get(ENV, "1") != "0"
        if not persist:
            return
        from memora_graph.onnx_embed import cache_root, writable_dir

        root = (Path(self._root) if self._root is not None else cache_root()) / "vectors"
        if not writable_dir(root):
            log.warning("memora: %s cannot be written; text vectors are kept in memory only (set MEMORA_CACHE_DIR "
                        "to a writable directory)", root)
            return
        path = root / f"{encoder_identity(self.encoder)}-{self.kind}.sqlite"
        for attempt in range(OPEN_TRIES):
            try:
                self._disk = _Disk(path, int(self.encoder.dim))
                return
            except sqlite3.OperationalError as exc:  # locked by another process (two workers creating the file
                # at once switch it to WAL together): the file is not damaged, so it is never set aside
                if attempt == OPEN_TRIES - 1:
                    log.warning("memora: %s is locked by another process (%s); text vectors are kept in memory "
                                "only this time", path, exc)
                    return
                time.sleep(0.05 * 2 ** attempt)
            except sqlite3.DatabaseError as exc:
                self._disk = self._start_again(path, exc)
                return

    def _start_again(self, path: Path, exc: Exception) -> _Disk | None:
        """A damaged file is set aside (`.damaged-<time>`) and a new one started."""
        aside = path.with_name(f"{path.name}.damaged-{int(time.time())}")
        log.warning("memora: %s is damaged (%s); set aside as %s, starting a new one", path, exc, aside.name)
        if self._disk is not None:
            self._disk.close()
        for suffix in ("", "-wal", "-shm"):
            try:
                os.replace(f"{path}{suffix}", f"{aside}{suffix}")
            except FileNotFoundError:
                pass
        try:
            return _Disk(path, int(self.encoder.dim))
        except (sqlite3.Error, OSError) as again:
            log.warning("memora: cannot start %s (%s); text vectors are kept in memory only", path, again)
            return None

    def encode(self, texts: list[str]) -> np.ndarray:
        with self._lock:
            return self._encode(texts)

    def _encode(self, texts: list[str]) -> np.ndarray:
        if not self._opened:
            self._open_disk()
        keys = [_key(t) for t in texts]
        todo = {k: t for k, t in zip(keys, texts) if k not in self._memory}
        if todo and self._disk is not None:
            try:
                got = self._disk.get(list(todo))
            except sqlite3.OperationalError as exc:  # a lock held past the timeout: the file is fine, encode
                log.warning("memora: could not read text vectors from %s (%s)", self._disk.path, exc)
                got = {}
            except sqlite3.DatabaseError as exc:
                self._disk, got = self._start_again(self._disk.path, exc), {}
            self._memory.update(got)
            self.from_disk += len(got)
            todo = {k: t for k, t in todo.items() if k not in got}
        if todo:
            t0 = time.perf_counter()
            new = {k: np.asarray(self.encoder.encode([t], kind=self.kind)[0], dtype=np.float32) for k, t in todo.items()}
            self.seconds += time.perf_counter() - t0
            self.encoded += len(new)
            self._memory.update(new)
            if self._disk is not None:
                try:
                    self._disk.put(new)
                except sqlite3.OperationalError as exc:  # full disk, a lock held past the timeout: keep going
                    log.warning("memora: could not keep text vectors in %s (%s)", self._disk.path, exc)
                except sqlite3.DatabaseError as exc:
                    self._disk = self._start_again(self._disk.path, exc)
        if not texts:
            return np.zeros((0, int(self.encoder.dim)), dtype=np.float32)
        return np.stack([self._memory[k] for k in keys])

    def close(self) -> None:
        if self._disk is not None:
            self._disk.close()
            self._disk = None


_QUERY: dict[tuple[int, str], TextVectors] = {}


def query_vectors(embedder=None, kind: str = "query") -> TextVectors:
    """The process-wide `TextVectors` of `embedder`'s query encoder (default: `get_embedder()`'s),
    which the offline reader, its planner and `memora ask` compare texts with. `kind` 'passage'
    embeds the texts compared with a query (e5 models prefix them differently; MiniLM does not),
    in a file of their own."""
    if embedder is None:
        from memora_graph.embed import get_embedder

        embedder = get_embedder()
    inner = getattr(embedder, "inner", embedder)
    encoder = getattr(inner, "query", inner)  # SplitEmbedder: its query side (ONNX by default)
    key = (id(encoder), kind)
    if key not in _QUERY:
        _QUERY[key] = TextVectors(encoder, kind=kind)
    return _QUERY[key]


__all__ = ["ENV", "TextVectors", "encoder_identity", "query_vectors"]

"""The live writer's checkpoint schedule: its write-ahead log bounded by bytes, moments and seconds.

Each `remember` commits one transaction, which Kùzu appends to the database's write-ahead log
(`P01.kuzu.wal`, flushed before the commit returns: durable from then on). Only a checkpoint
writes the changes into the database file and empties the log. Until then Kùzu holds them in
memory (about 27 bytes of buffer pool per byte of log, in the writer and in whoever replays the
log), and after a crash the next open replays the whole log: the longer the log, the more memory
and time a restart takes. So a live writer checkpoints as soon as any of these is reached:

| bound | default | option (remember, serve --writable) |
|---|---|---|
| the log holds `log_mb` MB | 4 | `--checkpoint-mb` |
| `moments` moments committed since the last checkpoint | 1000 | `--checkpoint-moments` |
| the oldest moment not checkpointed is `seconds` old | 60 | `--checkpoint-seconds` |

0 turns a bound off (all three off: only closing checkpoints). A clean close always
checkpoints. Checkpoints run in a thread of their own, after the remember that made one due has
answered (the next remember waits for it; when remembers come back to back and the thread cannot
get in for a second, the next remember runs it); while a consolidation reads the store (`Store.readers`)
a checkpoint waits for it to finish, unless the log is 4x past a bound (Kùzu waits up to ~6 s for
readers' transactions, then fails the checkpoint: it is then tried again 5 s later). A checkpoint
that fails loses nothing: the log keeps every commit until one succeeds.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from memora_graph.errors import DataError, StoreError

DEFAULT_LOG_MB = 4.0
DEFAULT_MOMENTS = 1000
DEFAULT_SECONDS = 60.0
MB = 1 << 20
HARD = 4  # past this many times a bound, a checkpoint no longer waits for readers to finish
RETRY_S = 5.0  # after a failed checkpoint
INLINE_S = 1.0  # a checkpoint due this long and not run by the thread runs in the next remember
log = logging.getLogger("memora_graph.integrity")


@dataclass(frozen=True)
class CheckpointPolicy:
    """When a live writer checkpoints (see the module): the first bound reached; 0 turns one off."""

    log_mb: float = DEFAULT_LOG_MB
    moments: int = DEFAULT_MOMENTS
    seconds: float = DEFAULT_SECONDS

    def __post_init__(self) -> None:
        for name in ("log_mb", "moments", "seconds"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                raise DataError(f"checkpoint policy, field '{name}': expected a number >= 0 (0: off), got {value!r}")

    @property
    def off(self) -> bool:
        return not (self.log_mb or self.moments or self.seconds)

    def describe(self) -> str:
        parts = [f"{self.log_mb:g} MB of log" if self.log_mb else "",
                 f"{self.moments} moments" if self.moments else "",
                 f"{self.seconds:g} s" if self.seconds else ""]
        return "checkpoint at " + (", ".join(p for p in parts if p) or "close only")

    def due(self, log_bytes: int, moments: int, age_s: float, readers: int = 0) -> str | None:
        """Which bound is reached (None: none, or readers to wait for short of `HARD` x a bound)."""
        if moments <= 0:
            return None
        over = [(name, got / bound) for name, got, bound in (("log", log_bytes, self.log_mb * MB),
                                                             ("moments", moments, self.moments),
                                                             ("seconds", age_s, self.seconds))
                if bound and got >= bound]
        if not over:
            return None
        if readers and max(r for _, r in over) < HARD:
            return None
        return over[0][0]


class Checkpointer:
    """Runs a live writer's checkpoints on its policy, in a thread of its own.

    `store()` gives the writer's store (None once closed); `writer_lock` is held by a remember
    from start to answer (a checkpoint runs between remembers); `store_lock` is held around every
    use of the store. `committed()` after each commit (outside `store_lock`) wakes the thread
    when a bound is reached; the thread also wakes on its own for the `seconds` bound."""

    def __init__(self, policy: CheckpointPolicy, store: Callable[[], object], writer_lock, store_lock,
                 after: Callable[[], None] | None = None):
        self.policy, self._after = policy, after  # after(): once a checkpoint completed (empties the journal)
        self._store, self._writer_lock, self._store_lock = store, writer_lock, store_lock
        self.moments = 0  # committed since the last checkpoint
        self._first_at: float | None = None  # monotonic time of the oldest commit not checkpointed
        self._retry_at = 0.0
        self._due_at: float | None = None  # when a checkpoint became due (None: none is)
        self.runs: list[dict] = []  # each checkpoint: why, the log's bytes, moments, seconds, ok
        self._wake, self._stop = threading.Event(), threading.Event()
        self._thread: threading.Thread | None = None
        if not policy.off:
            self._thread = threading.Thread(target=self._loop, name="memora-checkpoint", daemon=True)
            self._thread.start()

    def committed(self) -> None:
        """After each commit (the caller holds the writer's lock, not the store's): wake the
        thread if a bound is reached; if the thread could not get in for `INLINE_S` since (the
        remembers come back to back), checkpoint here."""
        now = time.monotonic()
        self.moments += 1
        if self._first_at is None:
            self._first_at = now
        reason = self._due()
        if reason is None:
            self._due_at = None
            return
        if self._due_at is None:
            self._due_at = now
        if now - self._due_at >= INLINE_S:
            self.run(reason)
        else:
            self._wake.set()

    def _due(self) -> str | None:
        store = self._store()
        if store is None or self._first_at is None or time.monotonic() < self._retry_at:
            return None
        return self.policy.due(store.wal_bytes(), self.moments, time.monotonic() - self._first_at, store.readers)

    def _loop(self) -> None:
        interval = max(0.2, min(5.0, self.policy.seconds / 4)) if self.policy.seconds else 5.0
        while not self._stop.is_set():
            self._wake.wait(interval)
            self._wake.clear()
            if self._stop.is_set() or not self._writer_lock.acquire(timeout=0.2):
                continue  # a remember holds it: it wakes this thread again once committed
            try:
                if not self._stop.is_set():
                    reason = self._due()
                    if reason is not None:
                        self.run(reason)
            finally:
                self._writer_lock.release()

    def run(self, reason: str = "asked") -> bool:
        """Checkpoint now (the caller holds the writer's lock, not the store's). Never raises: a
        failure is logged and tried again `RETRY_S` later (the log still holds every commit)."""
        store = self._store()
        if store is None:
            return False
        t0 = time.perf_counter()
        with self._store_lock:
            log_bytes, moments = store.wal_bytes(), self.moments
            try:
                store.checkpoint()
            except StoreError as exc:
                self._retry_at = time.monotonic() + RETRY_S
                self.runs.append({"reason": reason, "log_bytes": log_bytes, "moments": moments,
                                  "seconds": time.perf_counter() - t0, "ok": False})
                log.warning(f"{store.path}: checkpoint ({reason}) failed, the write-ahead log keeps every commit "
                            f"({log_bytes / MB:.1f} MB, {moments} moments); tried again in {RETRY_S:g} s: {exc}")
                return False
            if self._after is not None:
                self._after()
        self.moments, self._first_at, self._due_at = 0, None, None
        self.runs.append({"reason": reason, "log_bytes": log_bytes, "moments": moments,
                          "seconds": time.perf_counter() - t0, "ok": True})
        return True

    def stop(self) -> None:
        """End the thread (before the writer's store closes; the close checkpoints)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=10)

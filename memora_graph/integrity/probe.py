"""Child process of `memora_graph.files.probe` (and `replay`): open one database read-only (`--write`:
read-write, which replays its write-ahead log into it and checkpoints on close) and print its rows per
table as JSON. Run as `python -m memora_graph.integrity.probe DB PARTICIPANT [PARENT_PID] [--write]`; a
crash here (SIGSEGV on a damaged file or a foreign write-ahead log) only ends this process.

The buffer pool is capped (a damaged file cannot take the machine's memory), but never below what
replaying the write-ahead log needs: the cap is sized from the log (`store.replay_pool_bytes`; with
`--write`, at least the database's size, which the checkpoint on close needs) and doubled, up to Kùzu's default (most of the memory), while Kùzu says the pool is full. The JSON
also says what the replay took: the log's size, the pool it opened with, the memory it held
after replaying (`memory_bytes`: what the replayed changes occupy until a checkpoint) and the
seconds."""

from __future__ import annotations

import json
import os
import sys
import time


def _rss() -> int:
    """This process's resident memory now, in bytes."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def machine_pool() -> int:
    """Kùzu's default buffer pool: 80% of the machine's memory."""
    try:
        return int(0.8 * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (OSError, ValueError):
        return 1 << 40


def open_sized(db: str, log_bytes: int, read_only: bool = True):
    """A Store on `db`, its buffer pool sized from its log and doubled while short (a replay
    that fails for want of pool changes nothing); returns (store, pool bytes used, 0 meaning
    Kùzu's default)."""
    from memora_graph.store import ReplayError, Store, replay_pool_bytes

    pool, ceiling = replay_pool_bytes(log_bytes), machine_pool()
    if not read_only:  # the replayed log is checkpointed on close, which needs pool by the database's size:
        # a 2 GB database (1,000 h) replayed its 0.6 MB log in 256 MB and failed the checkpoint, after
        # Kùzu had already removed the log (1 GB checkpointed it)
        pool = max(pool, os.path.getsize(db) if os.path.exists(db) else 0)
    while True:
        if pool >= ceiling:
            pool = 0  # the last try: Kùzu's own default
        try:
            return Store(db, read_only=read_only, buffer_pool_bytes=pool), pool
        except ReplayError as exc:
            if not exc.short_of_pool or pool == 0:
                raise
            pool *= 2


def main(argv: list[str]) -> int:
    from memora_graph.errors import MemoraError
    from memora_graph.files import die_with_parent
    from memora_graph.store import wal_path

    write = "--write" in argv
    db, participant, *parent = [a for a in argv if a != "--write"]
    if parent:  # asked by a process that may be killed: go with it, not hold the file under the next one
        die_with_parent(int(parent[0]))
    wal = wal_path(db)
    log_bytes = wal.stat().st_size if wal.exists() else 0
    before, t0 = _rss(), time.perf_counter()
    try:
        store, pool = open_sized(db, log_bytes, read_only=not write)
        with store:
            replay = {"log_bytes": log_bytes, "pool_bytes": pool, "memory_bytes": max(0, _rss() - before),
                      "seconds": round(time.perf_counter() - t0, 3)}
            if write:  # replayed to be recorded: the caller counts the rows of the file as it is then
                tables, counts = {}, {}
            else:
                tables = store.table_counts(participant)
                counts = store.rows("store_counts", participant=participant)[0] if "Video" in tables else {}
        if write:
            replay["seconds_with_checkpoint"] = round(time.perf_counter() - t0, 3)
    except MemoraError as exc:
        print(str(exc))
        return 1
    print(json.dumps({"tables": tables, "counts": {k: int(v or 0) for k, v in counts.items()}, "replay": replay}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

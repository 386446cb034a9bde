"""Who may write a bank, and when: the manifest's lock (one read-modify-write at a time), the
participant lock (one build or forget of a participant at a time), and the write marks the
manifest carries while a process writes a participant's database (`WriteMarks`: if the process
dies, the mark says which write did not finish). Locks are POSIX locks across processes; where
`fcntl` is missing, builds run one participant at a time and the locks are no-ops."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

from memora_graph.errors import BankError

BUILD_LOCK = ".build.lock"
MANIFEST_LOCK = ".manifest.lock"
LOCK_FDS: dict[str, int] = {}  # per lock file, the one descriptor this process keeps open (POSIX record locks)


def now() -> str:
    """The time now, as the manifest records it (UTC, ISO 8601, to the second)."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def pid_alive(pid) -> bool:
    """Whether a process with this id runs on this machine (False for None or garbage)."""
    try:
        os.kill(int(pid), 0)
    except (OSError, ValueError, TypeError):
        return False
    return True


@contextmanager
def manifest_lock(directory: Path) -> Iterator[None]:
    """Exclusive access to a bank's manifest for a read-modify-write, across processes: the
    participants of a bank are built side by side by worker processes (`memora build --jobs`)."""
    directory.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # not POSIX: builds there run one participant at a time
        yield
        return
    with open(directory / MANIFEST_LOCK, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def lock_byte(participant: str) -> int:
    """The byte of BANK/.build.lock that stands for a participant: EPIC's P00-P99 their number (as
    before ids were free), any other id a 48-bit hash of it past those (a file's byte ranges may
    lie beyond its end; two ids sharing a byte is a 1 in 10^14 chance, and would only make one
    build wait for the other)."""
    import hashlib
    import re

    if re.fullmatch(r"P\d\d", participant):
        return int(participant[1:])
    return 100 + int.from_bytes(hashlib.blake2b(participant.encode(), digest_size=6).digest(), "big")


@contextmanager
def participant_lock(directory: Path, participant: str, wait_s: float = 10.0) -> Iterator[None]:
    """Exclusive, across processes, for building or forgetting one (valid) participant of the bank
    in `directory`: a byte-range lock on BANK/.build.lock (one byte per participant: `lock_byte`), held
    for the whole build. Waits up to `wait_s` (the worker of a build that was just killed dies a
    moment after it)."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    path = directory / BUILD_LOCK
    directory.mkdir(parents=True, exist_ok=True)
    key = str(path.resolve())
    if key not in LOCK_FDS:  # POSIX record locks belong to the process: keep one descriptor open
        LOCK_FDS[key] = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    fd, n = LOCK_FDS[key], lock_byte(participant)
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB, 1, n)
            break
        except OSError:
            if time.monotonic() >= deadline:
                raise BankError(f"{directory}: {participant} is being built (or forgotten) by another process; "
                                "wait for it to finish, then retry") from None
            time.sleep(0.1)
    try:
        yield
    finally:
        fcntl.lockf(fd, fcntl.LOCK_UN, 1, n)


class WriteMarks:
    """The manifest's `writing` map: per participant, the write under way (op, pid, since).
    Until the integrity record clears it, readers refuse the participant. `update` is the
    manifest's locked read-modify-write (`ManifestFile.update`), `exists` whether it exists."""

    def __init__(self, update: Callable[[Callable[[dict], None]], dict], exists: Callable[[], bool]):
        self.update = update
        self.exists = exists

    def mark(self, participant: str, op: str) -> None:
        """Say in the manifest that this process is about to write a participant's database."""
        mark = {"op": op, "pid": os.getpid(), "since": now()}
        self.update(lambda data: data.setdefault("writing", {}).__setitem__(participant, mark))

    def abandon(self, participant: str) -> None:
        """After this process's write of a participant failed: keep the mark (the write did not
        finish) but no longer as this process's own, so that later opens here check the
        participant like any reader does."""
        def change(data: dict) -> None:
            mark = data.get("writing", {}).get(participant)
            if mark and mark.get("pid") == os.getpid():
                mark["pid"] = None
                mark["failed_in"] = os.getpid()

        if self.exists():
            try:
                self.update(change)
            except OSError:  # e.g. a full disk: the mark stays this process's, and reads as unfinished once it exits
                pass

    def clear(self, participant: str) -> None:
        """Remove this process's own mark of a participant."""
        def change(data: dict) -> None:
            marks = data.get("writing", {})
            if marks.get(participant, {}).get("pid") == os.getpid():
                del marks[participant]
            if not marks:
                data.pop("writing", None)

        self.update(change)

    @staticmethod
    def drop(data: dict, participant: str) -> None:
        """In a manifest `data`: remove a participant's mark, whoever holds it (its write finished)."""
        marks = data.get("writing", {})
        marks.pop(participant, None)
        if not marks:
            data.pop("writing", None)

    @staticmethod
    def held_here(data: dict, participant: str) -> bool:
        """Whether this process holds the participant's write mark in a manifest `data`."""
        return data.get("writing", {}).get(participant, {}).get("pid") == os.getpid()

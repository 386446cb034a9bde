"""What can be checked about a participant database before Kùzu opens it.

Kùzu 0.11.3 has no page checksums: a damaged file can open and return wrong values, or crash
the process (SIGSEGV) on read, and it replays any write-ahead log it finds next to a database,
its own or not (a foreign one crashes it too). So the bank records a sha256 of each database
file after every write, when the file is closed and checkpointed (no log or shadow file next to
it), and checks the file against it before opening. A database whose content cannot be
vouched for that way (an interrupted write with a log to replay) is first opened in a child
process (`probe`), so that a crash there becomes an error message here.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

from memora_graph.errors import BankError

SIDE_SUFFIXES = (".wal", ".shadow")  # Kùzu's write-ahead log and the shadow pages of a checkpoint
PROBE_TIMEOUT_S = 120

_HASHED: dict[tuple, str] = {}  # (path, size, mtime_ns, ctime_ns, inode) -> sha256, for this process


def side_files(db: Path) -> list[Path]:
    """The write-ahead log / shadow files next to a database (none after a clean close)."""
    return [p for p in (db.with_name(db.name + s) for s in SIDE_SUFFIXES) if p.exists()]


def file_kind(st: os.stat_result) -> str:
    """What an lstat result is, in words: "file" for a regular file."""
    import stat

    mode = st.st_mode
    for test, name in ((stat.S_ISREG, "file"), (stat.S_ISLNK, "a symbolic link"), (stat.S_ISDIR, "a folder"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _key(path: Path, st: os.stat_result) -> tuple:
    return (str(path), st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)


def file_sha256(path: Path, st: os.stat_result | None = None) -> str:
    """sha256 of a file, hashed once per process for a given (size, mtime, ctime, inode): any
    write changes ctime, so a file changed since is hashed again."""
    st = st or path.stat()
    key = _key(path, st)
    if key not in _HASHED:
        with open(path, "rb") as fh:
            _HASHED[key] = hashlib.file_digest(fh, "sha256").hexdigest()
    return _HASHED[key]


def forget_hashes() -> None:
    """Forget every sha256 this process computed (a benchmark timing the first hash of a file)."""
    _HASHED.clear()


def die_with_parent(parent: int) -> None:
    """Make this (child) process end when `parent` does, kill -9 included (Linux: prctl
    PR_SET_PDEATHSIG). A probe left running by a killed writer keeps the database open (read-only),
    and the next writer then finds it "busy"; with this, the probe goes with the process that asked
    for it. Exits at once if `parent` is already gone. Elsewhere (no prctl) it does nothing."""
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, int(signal.SIGKILL), 0, 0, 0) != 0:  # 1 = PR_SET_PDEATHSIG
            return
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # it died before the request took effect: we were re-parented already
        os._exit(1)


def probe(db: Path, participant: str, timeout: float = PROBE_TIMEOUT_S) -> dict:
    """Open a database read-only in a child process (replaying its write-ahead log in memory, as
    Kùzu does, without writing anything) and count its rows per table. Returns the counts, or
    raises BankError naming the file when Kùzu fails or crashes on it."""
    cmd = [sys.executable, "-m", "memora_graph.integrity.probe", str(db), participant, str(os.getpid())]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).resolve().parents[2]),
                                                                      os.environ.get("PYTHONPATH", "")]))}
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        raise BankError(f"{db}: Kùzu did not finish opening it in {timeout:.0f} s, in a child process (stopped; a "
                        "damaged file can make it spin); it was not opened here") from None
    sides = ", ".join(p.name for p in side_files(db))
    with_sides = f" with {sides}" if sides else ""
    if res.returncode < 0:
        raise BankError(f"{db}: Kùzu crashed (signal {-res.returncode}) opening it{with_sides}, in a child process; "
                        f"the file{' or its log' if sides else ''} is damaged or does not belong to it. "
                        "Nothing was replayed or opened here.")
    if res.returncode != 0:
        why = (res.stdout.strip().splitlines() or res.stderr.strip().splitlines() or ["no output"])[-1]
        raise BankError(f"{db}: cannot be opened{with_sides} ({why})")
    return json.loads(res.stdout)

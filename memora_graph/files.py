"""What can be checked about a participant database before Kùzu opens it.

Kùzu 0.11.3 has no page checksums: a damaged file can open and return wrong values, or crash
the process (SIGSEGV) on read, and it replays any write-ahead log it finds next to a database,
its own or not (a foreign one crashes it too). So the bank records a sha256 of each database
file after every write, when the file is closed and checkpointed (no log or shadow file next to
it), and checks the file against it before opening. A database whose content cannot be
vouched for that way (an interrupted write with a log to replay) is first opened in a child
process (`probe`), so that a crash there becomes an error message here; a log is replayed into
its database in a child process too (`replay`), after a copy of it is kept (`keep_log`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from memora_graph.errors import BankError

SIDE_SUFFIXES = (".wal", ".shadow")  # Kùzu's write-ahead log and the shadow pages of a checkpoint
PROBE_TIMEOUT_S = 120
RECOVERY = ".recovery"  # BANK/.recovery/<db>-<UTC time>-<pid>/: copies of logs taken before they were replayed
KEEP_LOGS = 3  # copies kept per database (the oldest go)

_HASHED: dict[tuple, str] = {}  # (path, size, mtime_ns, ctime_ns, inode) -> sha256, for this process


@contextmanager
def staged_files(folder: Path) -> Iterator[Callable[[str], Path]]:
    """`with staged_files(out) as aside:` each `aside(name)` is a path to write `out/name` to, aside
    (`.name.partial-PID`); when the block ends they are all moved into place, so a reader never
    finds half of a folder's files. A block that fails leaves the folder as it was."""
    folder.mkdir(parents=True, exist_ok=True)
    staged: list[tuple[Path, Path]] = []

    def aside(name: str) -> Path:
        tmp = folder / f".{name}.partial-{os.getpid()}"
        staged.append((tmp, folder / name))
        return tmp

    try:
        yield aside
    except BaseException:
        for tmp, _ in staged:
            tmp.unlink(missing_ok=True)
        raise
    for tmp, final in staged:
        os.replace(tmp, final)


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


def keep_log(db: Path) -> Path | None:
    """Copy a database's write-ahead log (and shadow file) into BANK/.recovery/ before anything
    replays it into the database: what a repair started from, should it go wrong. Keeps the
    newest `KEEP_LOGS` copies of this database's. Returns the copy's folder (None: no log)."""
    db = Path(db)
    sides = side_files(db)
    if not sides:
        return None
    folder = db.parent / RECOVERY
    dest = folder / f"{db.name}-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}-{os.getpid()}"
    try:
        dest.mkdir(parents=True, exist_ok=True)
        for side in sides:
            shutil.copy2(side, dest / side.name)
    except OSError as exc:
        shutil.rmtree(dest, ignore_errors=True)
        size = sum(s.stat().st_size for s in sides) / 1e6
        raise BankError(f"{db}: could not keep a copy of {', '.join(s.name for s in sides)} ({size:.1f} MB) in "
                        f"{folder} before replaying it ({exc.strerror or exc}); nothing was replayed. Free some "
                        "space and retry.") from None
    for old in sorted(p for p in folder.glob(f"{db.name}-*") if p.is_dir())[:-KEEP_LOGS]:
        shutil.rmtree(old, ignore_errors=True)
    return dest


def probe(db: Path, participant: str, timeout: float = PROBE_TIMEOUT_S) -> dict:
    """Open a database read-only in a child process (replaying its write-ahead log in memory, as
    Kùzu does, without writing anything) and count its rows per table. Returns the counts (and,
    under "replay", what replaying the log took: `memora_graph.integrity.probe`), or raises
    BankError naming the file when Kùzu fails or crashes on it."""
    return _child(db, participant, timeout, write=False)


def replay(db: Path, participant: str, timeout: float = PROBE_TIMEOUT_S) -> dict:
    """Replay a database's write-ahead log into it in a child process (opened read-write with a
    buffer pool sized from the log, counted, checkpointed and closed), so a crash on a damaged
    log ends the child, not this process, and the log is replayed once. Keep a copy first
    (`keep_log`). Returns {"replay": what it took} (no row counts: the caller records the file next)."""
    return _child(db, participant, timeout, write=True)


def _child(db: Path, participant: str, timeout: float, write: bool) -> dict:
    cmd = [sys.executable, "-m", "memora_graph.integrity.probe", str(db), participant, str(os.getpid()),
           *(["--write"] if write else [])]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).resolve().parents[2]),
                                                                      os.environ.get("PYTHONPATH", "")]))}
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        raise BankError(f"{db}: Kùzu did not finish opening it in {timeout:.0f} s, in a child process (stopped; a "
                        "damaged file can make it spin); it was not opened here") from None
    sides = ", ".join(f"{p.name} ({p.stat().st_size / 1e6:.1f} MB)" for p in side_files(db))
    with_sides = f" with {sides}" if sides else ""
    if res.returncode < 0:
        kept = f" A copy of the log was kept in {Path(db).parent / RECOVERY}." if write else ""
        raise BankError(f"{db}: Kùzu crashed (signal {-res.returncode}) opening it{with_sides}, in a child process; "
                        f"the file{' or its log' if sides else ''} is damaged or does not belong to it. "
                        f"Nothing was replayed or opened here.{kept}")
    if res.returncode != 0:
        why = (res.stdout.strip().splitlines() or res.stderr.strip().splitlines() or ["no output"])[-1]
        if why.startswith(f"{db}: cannot be opened with its write-ahead log"):  # names the log, its size, what to do
            raise BankError(why)
        raise BankError(f"{db}: cannot be opened{with_sides} ({why})")
    return json.loads(res.stdout)

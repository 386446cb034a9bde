"""Ad-hoc Cypher over a bank (`memora query`, the MCP `cypher` tool): the read guard decides
what may run, then the statement runs in a child process that the kernel confines, under a time
limit and a memory limit, and hands back a bounded result.

Three lines of defence, each for what the one before cannot promise:

- The read guard (memora_graph/cypher_guard.py) refuses, with reasons, writes, files,
  extensions, other databases and the texts known to crash Kùzu.
- The child confines itself with Landlock (memora_graph/confine.py) before Kùzu opens anything:
  read-only, it can open the chosen participants' database files and nothing else; with
  `--write`, only a private working folder holding a hard link to the one database (Kùzu
  creates, writes and removes its write-ahead log and shadow file next to the database it
  opens, so it needs a folder; the bank's folder would let it create or remove any file there).
  No network. A statement the guard lets through by mistake still cannot read a file.
- The child is killed at its time limit (plus a grace period, Kùzu interrupts a query only
  between batches of rows) or when it grows past `memory_mb`; a crash of Kùzu ends the child,
  not the caller. Its answer is cut to `max_rows` rows and `max_bytes` bytes of Arrow IPC, so
  the caller never holds more; `--csv` output streams every row straight to the caller's
  standard output instead.

The parent does everything that touches the bank's other files: the integrity checks before
Kùzu opens a database, the manifest's write mark, the integrity record after a write. The
request to the child is JSON on its stdin; the reply on its stdout is one JSON header line
(`ok`, rows, cut, or the error), followed by the rows as an Arrow IPC stream.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from memora_graph.bank import Bank, verify_default
from memora_graph.confine import NO_GUARD_ENV, ConfinementError, mode as confinement_mode
from memora_graph.cypher_guard import Statement, check_param, check_participant, check_query
from memora_graph.errors import BankError, MemoraError, QueryRefused, QueryTimeout, StoreError
from memora_graph.files import side_files

DEFAULT_TIMEOUT = 30.0
MAX_TIMEOUT = 24 * 3600.0
MEMORY_MB = 2048  # the child's resident memory; a whole bank's databases take a few hundred MB
GRACE_SECONDS = 5.0  # after the time limit, for Kùzu to interrupt the query itself
STARTUP_SECONDS = 60.0  # for the child to start (a fresh interpreter importing Kùzu), on a busy machine
MAX_ROWS = 10_000  # rows handed back at most (`--max-rows`); the rest is counted, not sent
MAX_BYTES = 32 * 2**20  # bytes of Arrow IPC handed back at most
WORK_PREFIX = ".adhoc-write-"  # a --write child's private folder inside the bank


@dataclass
class QueryResult:
    """What a query handed back: at most `max_rows` rows and `max_bytes` bytes of them."""

    frame: pl.DataFrame
    total_rows: int  # rows the statement returned, before the cut
    cut: str | None = None  # None, "rows" or "bytes": why `frame` holds fewer than total_rows
    confined: bool = True  # whether the kernel confined the child
    streamed: bool = False  # --csv: the rows went to standard output as they were written

    @property
    def notice(self) -> str | None:
        if not self.cut:
            return None
        cap = "--max-rows" if self.cut == "rows" else "the size cap"
        return (f"result cut to its first {self.frame.height:,} of {self.total_rows:,} rows ({cap}); page through "
                f"the rest with SKIP n LIMIT m, or write every row with --csv > FILE")


def resolve_participants(bank: Bank, participant: object, params: dict, write: bool) -> list[str]:
    """Whose databases a query runs on: `--participant`, else `-p participant`, else (reads only)
    every participant of the bank. Both given and different is an error, not zero rows."""
    chosen = None
    if participant is not None:
        chosen = check_participant(participant, "--participant")
        if "participant" in params and params["participant"] != chosen:
            raise QueryRefused(f"--participant {chosen} and -p participant {params['participant']!r} disagree; "
                               "give one participant")
    elif "participant" in params:
        chosen = check_participant(params["participant"], "-p participant")
    if write and chosen is None:
        raise QueryRefused("--write writes into one participant's database: name it with --participant P01")
    pids = [chosen] if chosen else bank.participants()
    known = set(bank.participants())
    missing = [p for p in pids if p not in known]
    if missing:
        raise BankError(f"{bank.path}: participant {missing[0]} is not in this bank (has: "
                        f"{', '.join(sorted(known)) or 'none'})")
    return pids


def bind_params(statement: Statement, params: dict, participant: str) -> dict:
    """The values of the statement's $parameters. `$participant` is the participant whose
    database is read unless given; a parameter given but not used is an error (Kùzu refuses it),
    except `participant`, which also chooses the database."""
    unused = [k for k in params if k not in statement.params and k != "participant"]
    if unused:
        raise QueryRefused(f"-p {unused[0]} is given but the query has no ${unused[0]}")
    bound = {}
    for name in statement.params:
        if name in params:
            bound[name] = check_param(name, params[name])
        elif name == "participant":
            bound[name] = participant
        else:
            raise QueryRefused(f"the query uses ${name} but no value is given (-p {name} VALUE)")
    return bound


def _check_limits(timeout: object, max_rows: object, max_bytes: object) -> None:
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not math.isfinite(timeout) \
            or not 0 < timeout <= MAX_TIMEOUT:
        raise QueryRefused(f"--timeout must be a number of seconds above 0 and at most {MAX_TIMEOUT:.0f}, "
                           f"not {timeout!r}")
    for name, value in (("--max-rows", max_rows), ("the byte cap", max_bytes)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise QueryRefused(f"{name} must be a whole number of at least 1, not {value!r}")


def _unguarded(cypher: object, write: bool) -> Statement:
    """Test-only (MEMORA_TEST_NO_GUARD): the statement as given, to show what the kernel alone stops."""
    if not isinstance(cypher, str):
        raise QueryRefused("refused: a query is text")
    params = tuple(dict.fromkeys(re.findall(r"\$([A-Za-z_][A-Za-z0-9_]*)", cypher)))
    return Statement(text=cypher, mode="write" if write else "read", clauses=(), procedures=(), params=params)


def run_query(bank_path: str | Path, cypher: str, params: dict | None = None, participant: str | None = None,
              write: bool = False, timeout: float = DEFAULT_TIMEOUT, memory_mb: int = MEMORY_MB,
              grace: float = GRACE_SECONDS, max_rows: int = MAX_ROWS, max_bytes: int = MAX_BYTES,
              csv_fd: int | None = None, require_confinement: bool = False) -> QueryResult:
    """Run one ad-hoc statement over a bank and return at most `max_rows` rows / `max_bytes`
    bytes of its result (every participant's, concatenated, unless one is chosen). Read-only
    unless `write`, which needs exactly one participant and allows data writes only. With
    `csv_fd`, every row is written as CSV to that file descriptor instead (no cap). Raises
    QueryRefused before anything runs (also where the kernel cannot confine the child and
    `require_confinement`), QueryTimeout past `timeout` seconds, StoreError / BankError for
    what Kùzu or the bank reports."""
    statement = _unguarded(cypher, write) if os.environ.get(NO_GUARD_ENV) else check_query(cypher, write=write)
    _check_limits(timeout, max_rows, max_bytes)
    confinement = confinement_mode()
    if require_confinement and not confinement.confined:
        raise QueryRefused(f"ad-hoc Cypher is off: {confinement.describe()}")
    params = dict(params or {})
    bank = Bank(bank_path)
    pids = resolve_participants(bank, participant, params, write)
    jobs = []
    for p in pids:
        db = bank.checked_db_file(p)
        counts = _checked(bank, p)
        jobs.append({"participant": p, "db": str(db), "params": bind_params(statement, params, p), "counts": counts})
    request = {"bank": str(bank.path), "jobs": jobs, "cypher": statement.text, "write": write,
               "timeout": float(timeout), "memory_mb": memory_mb, "grace": grace, "max_rows": max_rows,
               "max_bytes": max_bytes, "confine": confinement.confined, "csv_fd": csv_fd}
    if not write:
        result = _in_child(request, csv_fd)
    else:
        result = _write_in_child(bank, pids[0], request, csv_fd)
    result.confined = confinement.confined
    return result


def _checked(bank: Bank, participant: str) -> dict | None:
    """The checks a read open runs before Kùzu touches the file (integrity, write marks); the
    manifest's counts for the child to compare, or None under --no-verify."""
    data = bank.manifest()
    if not verify_default():
        return None
    bank.notify(data, skip=participant)
    bank.check(participant, data)
    return data["participants"][participant].get("counts", {})


def _write_in_child(bank: Bank, participant: str, request: dict, csv_fd: int | None) -> QueryResult:
    """A --write query: the manifest's write mark, a private folder with a hard link to the
    database for the confined child, and the integrity record (or the kept mark) afterwards."""
    db = Path(request["jobs"][0]["db"])
    work = bank.path / f"{WORK_PREFIX}{participant}-{os.getpid()}-{threading.get_ident()}"
    with bank.participant_lock(participant):
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(mode=0o700)
        try:
            os.link(db, work / db.name)
        except OSError as exc:
            shutil.rmtree(work, ignore_errors=True)
            raise BankError(f"{db}: --write needs a hard link to it inside the bank ({exc.strerror or exc}); this "
                            "file system does not offer one") from None
        request["jobs"][0]["db"] = str(work / db.name)
        request["work"] = str(work)
        bank.mark_writing(participant, "write")
        opened = True  # unless the child says it refused the database before opening it to write
        try:
            result = _in_child(request, csv_fd)
        except MemoraError as exc:  # name the bank's file, not the private link
            opened = getattr(exc, "opened", True)
            raise type(exc)(str(exc).replace(str(work / db.name), str(db))) from None
        finally:
            left = side_files(work / db.name)
            for side in left:  # a killed write: its log goes next to the database, as an interrupted build's
                os.replace(side, db.with_name(side.name))
            shutil.rmtree(work, ignore_errors=True)
            if left:
                bank.abandon_writing(participant)
            elif opened:
                bank.record_integrity(participant)
            else:  # refused before writing (counts differ from the manifest): the file is as it was
                bank.clear_writing(participant)
    return result


# -- the child process ----------------------------------------------------------------------------
# `python -m memora_graph.adhoc` reads its request (JSON) on stdin and writes one reply on stdout.
# A plain subprocess rather than multiprocessing: a spawned multiprocessing child imports the
# caller's main module again, which a script without a main guard would run.


def _in_child(request: dict, csv_fd: int | None = None) -> QueryResult:
    import subprocess
    import sys

    root = str(Path(__file__).resolve().parents[1])  # this checkout's memora_graph, whatever the caller's path
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])])}
    timeout, grace, write = request["timeout"], request["grace"], request["write"]
    # the CSV target under a number of its own: the child's 0-2 are its pipes
    passed = os.dup(csv_fd) if csv_fd is not None else None
    request = {**request, "csv_fd": passed, "parent": os.getpid()}
    try:
        child = subprocess.Popen([sys.executable, "-m", "memora_graph.adhoc"], stdin=subprocess.PIPE,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                                 pass_fds=(passed,) if passed is not None else ())
        try:
            # the child stops itself at the time limit; this is the backstop, start-up included
            out, err = child.communicate(json.dumps(request).encode(), timeout=timeout + grace + STARTUP_SECONDS)
        except subprocess.TimeoutExpired:
            child.kill()
            child.communicate()
            raise QueryTimeout(f"the query ran past its time limit of {timeout:g} s and was stopped; nothing it "
                               "did was kept. Narrow it, or give it more time with --timeout SECONDS") from None
    finally:
        if passed is not None:
            os.close(passed)
    head, _, body = out.partition(b"\n")
    try:
        header = json.loads(head)
    except ValueError:  # no reply: the child died
        raise _died(child.returncode, write, err) from None
    if "error" in header:
        kind, text = header["error"], header["message"]
        exc = {"QueryRefused": QueryRefused, "QueryTimeout": QueryTimeout, "BankError": BankError}.get(
            kind, StoreError)(text)
        exc.opened = header.get("opened", True)
        raise exc
    if header.get("csv"):
        return QueryResult(pl.DataFrame(), header["rows"], None, streamed=True)
    if len(body) > request["max_bytes"] + 2**20:
        raise StoreError(f"the query process answered {len(body)} bytes, more than its cap of {request['max_bytes']}")
    frame = pl.read_ipc_stream(body) if body else pl.DataFrame()
    return QueryResult(frame, header["rows"], header.get("cut"))


def _died(exitcode: int | None, write: bool, err: bytes = b"") -> StoreError:
    kept = ("a write in progress was not committed" if write
            else "the bank was open read-only and is unchanged")
    last = err.decode("utf-8", "replace").strip().splitlines()[-1:] if err else []
    said = f" (it said: {last[0][:300]})" if last else ""
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        return StoreError(f"Kùzu crashed ({name}) running this query; {kept}. The query may be valid: "
                          f"simplify it, and report it if it should work{said}")
    return StoreError(f"the query process ended without an answer (exit code {exitcode}); {kept}{said}")


class _Reply:
    """The child's one answer, written once, by the query or by the watchdog stopping it."""

    def __init__(self, stream):
        self._stream = stream
        self._lock = threading.Lock()
        self._sent = False

    def send(self, header: dict, body: bytes = b"") -> bool:
        with self._lock:
            if self._sent:
                return False
            self._stream.write(json.dumps(header).encode() + b"\n" + body)
            self._stream.flush()
            self._sent = True
            return True

    def error(self, kind: str, message: str, opened: bool = True) -> bool:
        return self.send({"error": kind, "message": message, "opened": opened})


def _ipc(frame: pl.DataFrame) -> bytes:
    import io

    buf = io.BytesIO()
    frame.write_ipc_stream(buf)
    return buf.getvalue()


def _capped(frame: pl.DataFrame, max_rows: int, max_bytes: int) -> tuple[bytes, str | None]:
    """The frame's first rows as Arrow IPC: at most `max_rows` rows and `max_bytes` bytes."""
    cut = None
    if frame.height > max_rows:
        frame, cut = frame.head(max_rows), "rows"
    body = _ipc(frame)
    while len(body) > max_bytes and frame.height:
        keep = min(frame.height - 1, int(frame.height * max_bytes / len(body) * 0.9))
        frame, cut = frame.head(max(keep, 0)), "bytes"
        body = _ipc(frame)
    return body, cut


def _warm_up(csv: bool) -> None:
    """Load, before confinement, the modules a query's answer goes through (after it, the child
    can open no library file): Arrow to polars, the IPC writer, the CSV writer if asked for."""
    import pyarrow as pa

    frame = pl.from_arrow(pa.table({"a": [1], "b": ["x"], "c": [[1.0]]}))
    pl.read_ipc_stream(_ipc(frame))
    if csv:
        from memora_graph.output import render

        render(frame, "csv")


def _child_main() -> None:
    import sys

    reply = _Reply(os.fdopen(os.dup(1), "wb"))
    os.dup2(2, 1)  # anything printed (by Kùzu or a library) goes to stderr, not into the reply
    try:
        request = json.loads(sys.stdin.buffer.read())
        if not request["write"] and request.get("parent"):
            # a read goes with the process that asked for it (a killed server must not leave a query
            # holding the database open read-only, which the next writer would find "busy"); a
            # write runs to its commit or its time limit, as before
            from memora_graph.files import die_with_parent

            die_with_parent(int(request["parent"]))
        # everything the query needs is loaded and opened before the child confines itself
        from memora_graph.confine import confine
        from memora_graph.queries import load_queries
        from memora_graph.store import Store

        load_queries()
        _warm_up(request.get("csv_fd") is not None)
        statm = os.open("/proc/self/statm", os.O_RDONLY) if os.path.exists("/proc/self/statm") else None
        jobs, write = request["jobs"], request["write"]
        if request["confine"]:
            reads = [Path(j["db"]) for j in jobs]
            reads += [s for j in jobs for s in side_files(Path(j["db"]))]  # --no-verify: a log Kùzu replays
            confine(reads, Path(request["work"]) if write else None)
    except ConfinementError as exc:
        reply.error("QueryRefused", f"the query process could not confine itself, so nothing ran: {exc}", False)
        os._exit(0)
    except Exception as exc:  # noqa: BLE001 - words for the caller, never a traceback
        reply.error("StoreError", f"the query process could not start ({type(exc).__name__}: {exc})", False)
        os._exit(0)
    timeout, grace, memory_mb = request["timeout"], request["grace"], request["memory_mb"]
    _watch(reply, time.monotonic() + timeout + grace, timeout, memory_mb, write, statm)
    deadline = time.monotonic() + timeout
    opened = False  # whether a database was opened to write past the count check
    try:
        bank = Bank(request["bank"])  # for its messages: the child opens no bank file but the databases
        frames = []
        for job in jobs:
            left = deadline - time.monotonic()
            if left <= 0:
                raise QueryTimeout(f"the query ran past its time limit of {timeout:g} s (after {len(frames)} of "
                                   f"{len(jobs)} participants) and was stopped; give it more time with --timeout")
            with Store(job["db"], read_only=not write) as store:
                if job["counts"] is not None:
                    bank.verify_counts(job["participant"], store, job["counts"])
                opened = True
                store.set_timeout(left)
                frames.append(store.query(request["cypher"], job["params"]))
        frame = pl.concat(frames, how="vertical_relaxed") if frames else pl.DataFrame()
        if request.get("csv_fd") is not None:
            from memora_graph.output import render

            with os.fdopen(request["csv_fd"], "w", closefd=False) as out:
                out.write(render(frame, "csv"))
            reply.send({"ok": True, "rows": frame.height, "csv": True})
        else:
            body, cut = _capped(frame, request["max_rows"], request["max_bytes"])
            reply.send({"ok": True, "rows": frame.height, "cut": cut}, body)
    except MemoraError as exc:
        reply.error(type(exc).__name__, str(exc), opened)
    except Exception as exc:  # noqa: BLE001 - words for the caller, never a traceback
        reply.error("StoreError", f"{type(exc).__name__}: {exc}", opened)
    os._exit(0)  # at once: nothing left to clean up that the caller waits for


def _watch(reply: _Reply, hard_deadline: float, timeout: float, memory_mb: int, write: bool,
           statm: int | None) -> None:
    """Stop this process past `hard_deadline` (Kùzu interrupts a query only between batches of
    rows) or when its resident memory passes `memory_mb` (Linux /proc, opened before the child
    confined itself; elsewhere time alone)."""
    page = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
    limit = memory_mb * 2**20
    kept = "a write in progress was not committed" if write else "the bank is unchanged"

    def watch() -> None:
        while True:
            why = None
            if time.monotonic() > hard_deadline:
                kind, why = "QueryTimeout", (f"the query ran past its time limit of {timeout:g} s and was stopped "
                                             f"(Kùzu could not interrupt it); {kept}. Narrow it, or give it more "
                                             "time with --timeout SECONDS")
            else:
                try:
                    rss = int(os.pread(statm, 128, 0).split()[1]) * page if statm is not None else 0
                except (OSError, ValueError, IndexError):
                    rss = 0
                if rss > limit:
                    kind, why = "StoreError", (f"the query used more than {memory_mb} MB of memory and was stopped; "
                                               f"{kept}. Narrow it (LIMIT, a WHERE on the participant or video)")
            if why is not None:
                reply.error(kind, why)
                os._exit(3)
            time.sleep(0.05)

    threading.Thread(target=watch, daemon=True).start()


if __name__ == "__main__":
    _child_main()

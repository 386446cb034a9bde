"""Ad-hoc Cypher over a bank (`memora query`): the read guard decides what may run, then the
statement runs in a child process under a time limit and a memory limit.

The guard (memora_graph/cypher_guard.py) keeps out writes, files, extensions, other databases
and the texts known to crash Kùzu. The child process is for what no static check can bound:
Kùzu interrupts a query at its time limit only between batches of rows, so one expression
(`rpad('', 200000000, 'x')`, `range(1, 20000000)`: 11 GB) or its parser (nested CASE) can run
for minutes and fill memory before the limit applies. The child is killed at the limit (plus
a grace period) or when it grows past `memory_mb`, and a crash of Kùzu ends the child, not the
caller: each becomes a clear error. Starting the child costs about half a second.
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from pathlib import Path

import polars as pl

from memora_graph.bank import Bank
from memora_graph.cypher_guard import Statement, check_param, check_participant, check_query
from memora_graph.errors import BankError, MemoraError, QueryRefused, QueryTimeout, StoreError

DEFAULT_TIMEOUT = 30.0
MAX_TIMEOUT = 24 * 3600.0
MEMORY_MB = 2048  # the child's resident memory; a whole bank's databases take a few hundred MB
GRACE_SECONDS = 5.0  # after the time limit, for Kùzu to interrupt the query itself
STARTUP_SECONDS = 60.0  # for the child to start (a fresh interpreter importing Kùzu), on a busy machine


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


def run_query(bank_path: str | Path, cypher: str, params: dict | None = None, participant: str | None = None,
              write: bool = False, timeout: float = DEFAULT_TIMEOUT, memory_mb: int = MEMORY_MB,
              grace: float = GRACE_SECONDS) -> pl.DataFrame:
    """Run one ad-hoc statement over a bank and return its rows (every participant's, concatenated,
    unless one is chosen). Read-only unless `write`, which needs exactly one participant and
    allows data writes only. Raises QueryRefused before anything runs, QueryTimeout past
    `timeout` seconds (the child is killed `grace` seconds later if Kùzu cannot interrupt the
    query), StoreError / BankError for what Kùzu or the bank reports."""
    statement = check_query(cypher, write=write)
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not math.isfinite(timeout) \
            or not 0 < timeout <= MAX_TIMEOUT:
        raise QueryRefused(f"--timeout must be a number of seconds above 0 and at most {MAX_TIMEOUT:.0f}, "
                           f"not {timeout!r}")
    params = dict(params or {})
    bank = Bank(bank_path)
    pids = resolve_participants(bank, participant, params, write)
    jobs = [(p, bind_params(statement, params, p)) for p in pids]
    return _in_child(str(bank.path), jobs, statement.text, write, float(timeout), memory_mb, grace)


# -- the child process ----------------------------------------------------------------------------
# `python -m memora_graph.adhoc` reads its request (a pickle) on stdin and writes one reply (a
# pickle) on stdout. A plain subprocess rather than multiprocessing: a spawned multiprocessing
# child imports the caller's main module again, which a script without a main guard would run.


def _in_child(bank_path: str, jobs: list, cypher: str, write: bool, timeout: float, memory_mb: int,
              grace: float = GRACE_SECONDS) -> pl.DataFrame:
    import pickle
    import subprocess
    import sys

    root = str(Path(__file__).resolve().parents[1])  # this checkout's memora_graph, whatever the caller's path
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])])}
    request = pickle.dumps((bank_path, jobs, cypher, write, timeout, memory_mb, grace))
    child = subprocess.Popen([sys.executable, "-m", "memora_graph.adhoc"], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        # the child stops itself at the time limit; this is the backstop, start-up included
        out, err = child.communicate(request, timeout=timeout + grace + STARTUP_SECONDS)
    except subprocess.TimeoutExpired:
        child.kill()
        child.communicate()
        raise QueryTimeout(f"the query ran past its time limit of {timeout:g} s and was stopped; nothing it did "
                           "was kept. Narrow it, or give it more time with --timeout SECONDS") from None
    try:
        message = pickle.loads(out)
    except Exception:  # noqa: BLE001 - no reply: the child died
        raise _died(child.returncode, write, err) from None
    if message[0] == "ok":
        return message[1]
    _, kind, text = message
    raise {"QueryRefused": QueryRefused, "QueryTimeout": QueryTimeout, "BankError": BankError}.get(kind, StoreError)(text)


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

    def send(self, message: tuple) -> bool:
        import pickle

        with self._lock:
            if self._sent:
                return False
            try:
                data = pickle.dumps(message)
            except Exception as exc:  # noqa: BLE001 - a value that cannot travel: say so
                data = pickle.dumps(("error", "StoreError", f"the result cannot be returned ({exc})"))
            self._stream.write(data)
            self._stream.flush()
            self._sent = True
            return True


def _child_main() -> None:
    import pickle
    import sys

    reply = _Reply(os.fdopen(os.dup(1), "wb"))
    os.dup2(2, 1)  # anything printed (by Kùzu or a library) goes to stderr, not into the reply
    bank_path, jobs, cypher, write, timeout, memory_mb, grace = pickle.loads(sys.stdin.buffer.read())
    _watch(reply, time.monotonic() + timeout + grace, timeout, memory_mb, write)
    deadline = time.monotonic() + timeout
    try:
        bank = Bank(bank_path)
        frames = []
        for p, params in jobs:
            left = deadline - time.monotonic()
            if left <= 0:
                raise QueryTimeout(f"the query ran past its time limit of {timeout:g} s (after {len(frames)} of "
                                   f"{len(jobs)} participants) and was stopped; give it more time with --timeout")
            with bank.open(p, read_only=not write) as store:
                store.set_timeout(left)
                frames.append(store.query(cypher, params))
        frame = pl.concat(frames, how="vertical_relaxed") if frames else pl.DataFrame()
        message = ("ok", frame)
    except MemoraError as exc:
        message = ("error", type(exc).__name__, str(exc))
    except Exception as exc:  # noqa: BLE001 - words for the caller, never a traceback
        message = ("error", "StoreError", f"{type(exc).__name__}: {exc}")
    reply.send(message)
    os._exit(0)  # at once: nothing left to clean up that the caller waits for


def _watch(reply: _Reply, hard_deadline: float, timeout: float, memory_mb: int, write: bool) -> None:
    """Stop this process past `hard_deadline` (Kùzu interrupts a query only between batches of
    rows) or when its resident memory passes `memory_mb` (Linux /proc; elsewhere time alone)."""
    statm = Path("/proc/self/statm")
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
                    rss = int(statm.read_text().split()[1]) * page
                except (OSError, ValueError, IndexError):
                    rss = 0
                if rss > limit:
                    kind, why = "StoreError", (f"the query used more than {memory_mb} MB of memory and was stopped; "
                                               f"{kept}. Narrow it (LIMIT, a WHERE on the participant or video)")
            if why is not None:
                reply.send(("error", kind, why))
                os._exit(3)
            time.sleep(0.05)

    threading.Thread(target=watch, daemon=True).start()


if __name__ == "__main__":
    _child_main()

"""A served call's time budget: every call runs in a thread of its own, off the server's event
loop, and is answered "took too long" once it runs past its budget; its work is then stopped.

How the work stops: Python cannot kill a thread, so the call's thread is asked to stop twice
over. `StopCall` is raised inside it (CPython's `PyThreadState_SetAsyncExc`: it lands at the next
Python instruction the thread runs, so a loop in Python stops within milliseconds and its `with
lock:` blocks release their locks), and the tool's own interrupt runs (a Kùzu query in progress
is interrupted between batches of rows: `Connection.interrupt`). What the stopped call held (a
participant's open view, whose caches it may have left half-filled) is then discarded by the
`after_stop` hook, and the next call opens it afresh. Work in one long C call that does neither
(a regular expression, a numpy kernel) finishes on its own; the caller has been answered at the
budget regardless. A call whose half-done work must not be cut (a `remember` that commits) is
started with `stoppable=False`: it is answered at the budget, finishes, and is idempotent to
retry. A Cypher call is a child process under its own time limit (memora_graph/adhoc.py),
capped at the budget.

    call = Call(lambda: work(), on_done=wake)
    call.start()
    call.wait(10.0)    # True when it finished; else call.stop() and answer CallTimeout
"""

from __future__ import annotations

import ctypes
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from memora_graph.errors import MemoraError

DEFAULT_CALL_TIMEOUT = 10.0  # seconds a served call may run (`memora serve --call-timeout`)
MAX_CALL_TIMEOUT = 3600.0
MAX_CALLS = 64  # calls in flight at once (each a thread); past it a call is refused as busy


class CallTimeout(MemoraError):
    """A served call ran past its time budget; its work was stopped (or, for a write, left to
    finish)."""


class StopCall(BaseException):
    """Raised inside a call's thread to stop its work. A BaseException, so that no tool's
    `except Exception` swallows it."""


_local = threading.local()  # .call: the Call whose work this thread runs


@contextmanager
def shield() -> Iterator[None]:
    """Work that must not be cut halfway (opening a participant's view: cut at every budget, a
    slow open would never complete). A stop asked for meanwhile takes effect when it ends: the
    caller was answered at the budget regardless."""
    call = getattr(_local, "call", None)
    if call is None:
        yield
        return
    with call._state:
        call._shielded += 1
    try:
        yield
    finally:
        with call._state:
            call._shielded -= 1
            deferred = call._shielded == 0 and call._deferred
            call._deferred = False
        if deferred:
            raise StopCall


def _raise_in(thread_id: int, exc: type[BaseException] | None) -> int:
    """Make `exc` pending in the thread `thread_id` (None: clear a pending one); the threads it reached."""
    return ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(thread_id),
                                                      ctypes.py_object(exc) if exc is not None else None)


class Call:
    """One call's work in a thread of its own. `on_done()` runs in that thread once the work has
    finished (or been stopped); `after_stop()` too, before it, when the call was stopped."""

    def __init__(self, work: Callable[[], Any], *, stoppable: bool = True, interrupt: Callable[[], None] | None = None,
                 after_stop: Callable[[], None] | None = None, on_done: Callable[[], None] | None = None,
                 name: str = "memora-call"):
        self._work, self.stoppable, self._interrupt, self._after_stop = work, stoppable, interrupt, after_stop
        self.on_done = on_done
        self._state = threading.Lock()  # orders the thread's "finished" against stop()'s "stopping"
        self._finished = self._stopping = False
        self._shielded, self._deferred = 0, False
        self.injected = False  # whether StopCall was raised at an arbitrary instruction (not at a shield's end)
        self._done = threading.Event()
        self._outcome: tuple[bool, Any] | None = None  # (ok, result or exception)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> Call:
        self._thread.start()
        return self

    def _run(self) -> None:
        # A StopCall may land at any instruction until the thread marks itself finished (under
        # _state, which stop() takes to raise it: it is raised at most once, and never after).
        _local.call = self
        while True:
            try:
                if self._outcome is None:
                    try:
                        self._outcome = (True, self._work())
                    except BaseException as exc:  # noqa: BLE001 - handed to the caller
                        self._outcome = (False, exc)
                with self._state:
                    self._finished = True
                    if self._stopping:
                        _raise_in(threading.get_ident(), None)  # one still pending must not outlive the work
                break
            except StopCall as exc:
                if self._outcome is None:
                    self._outcome = (False, exc)
        try:
            if self._stopping and self._after_stop is not None:
                self._after_stop()
        finally:
            self._done.set()
            if self.on_done is not None:
                self.on_done()

    @property
    def thread_id(self) -> int | None:
        return self._thread.ident

    @property
    def stopped(self) -> bool:
        return self._stopping

    def wait(self, timeout: float | None) -> bool:
        """Whether the work finished within `timeout` seconds."""
        return self._done.wait(timeout)

    def done(self) -> bool:
        return self._done.is_set()

    def stop(self) -> bool:
        """Stop the work (see the module docstring); False when it had already finished."""
        with self._state:
            if self._finished or self._stopping:
                return False
            self._stopping = True
            if not self.stoppable:
                return True
            if self._shielded:
                self._deferred = True
                return True
            if self._thread.ident is not None:
                _raise_in(self._thread.ident, StopCall)
                self.injected = True
        if self._interrupt is not None:
            try:
                self._interrupt()
            except Exception:  # noqa: BLE001 - the work is stopping anyway; an interrupt that fails changes nothing
                pass
        return True

    def result(self) -> Any:
        """The work's result, or its exception raised (call once it is done)."""
        assert self._outcome is not None
        ok, value = self._outcome
        if ok:
            return value
        raise value

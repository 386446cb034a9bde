"""Running tasks on Ray from the driver: connecting, submitting, retrying, progress.

`cluster(executor)` connects to `--ray-address` (or starts a local Ray instance, stopped again
when the command ends). `run_tasks` submits one task per job, at most `in_flight` at a time (a
participant's snapshot is taken just before its task is sent, so the driver never holds every
database at once), retries a failed task `executor.retries` times, and calls `on_done` on the
driver for each result as it arrives, so finished work is installed while the rest runs (a
killed driver keeps it). Tasks report progress through a small actor the driver drains; an
event is forwarded once per id, so a retried task does not advance the bar twice.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from memora_graph.executors import Executor, TasksFailed, cpu_count, require_ray

log = logging.getLogger("memora_graph.executors")
ENV_PREFIXES = ("MEMORA_",)  # settings tasks inherit from the driver (e.g. MEMORA_NO_VERIFY)
_PROCESS: dict = {}  # per worker process: whether threads were limited, model load time not yet reported


@dataclass
class Outcome:
    key: str
    attempts: int = 0
    value: Any = None
    error: str | None = None


@contextmanager
def cluster(ex: Executor) -> Iterator[Any]:
    """Ray, connected: to `ex.address`, to the instance this process already joined, or to a
    new local instance (stopped on exit)."""
    ray = require_ray()
    if ray.is_initialized():
        yield ray
        return
    env = {k: v for k, v in os.environ.items() if k.startswith(ENV_PREFIXES)}
    kwargs: dict[str, Any] = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING,
                                  runtime_env={"env_vars": env} if env else None)
    if ex.address:
        ray.init(address=ex.address, **kwargs)
    else:
        ray.init(address="local", num_cpus=ex.num_cpus or cpu_count(), **kwargs)
    try:
        yield ray
    finally:
        ray.shutdown()


def _sink_class(ray):
    @ray.remote(num_cpus=0)
    class ProgressSink:
        """Collects the tasks' progress events until the driver drains them."""

        def __init__(self):
            self.events: list = []

        def add(self, key: str, event_id, payload) -> None:
            self.events.append((key, event_id, payload))

        def drain(self) -> list:
            out, self.events = self.events, []
            return out

    return ProgressSink


def _attempt(fn: Callable, key: str, attempt: int, fail: int, sink, args: tuple, kwargs: dict):
    """Runs on a worker: one attempt of one job."""
    if attempt <= fail:
        raise RuntimeError(f"injected failure of {key}, attempt {attempt} (Executor.fail_attempts)")
    import ray

    args = tuple(ray.get(a) if isinstance(a, ray.ObjectRef) else a for a in args)  # shared objects, put once

    def progress(event_id, payload) -> None:
        sink.add.remote(key, event_id, payload)  # fire and forget; one caller's calls arrive in order

    return fn(*args, progress=progress, **kwargs)


def error_text(exc: BaseException) -> str:
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException):
        return f"{type(cause).__name__}: {cause}"
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[-1] if text else ''}"


def run_tasks(ex: Executor, fn: Callable, jobs: list[tuple[str, Callable[[int], tuple[tuple, dict]]]], *,
              num_cpus: float = 1, in_flight: int | None = None,
              on_event: Callable[[str, Any], None] | None = None,
              on_done: Callable[[str, Any], None] | None = None,
              on_retry: Callable[[str, int, str], None] | None = None) -> dict[str, Outcome]:
    """Run `fn(*args, progress=..., **kwargs)` as one Ray task per job `(key, make)`, where
    `make(i)` gives the job's (args, kwargs) when it is submitted (i: the job's index, e.g. to
    pick a model server). Returns every job's Outcome; a job that failed `1 + ex.retries` times
    has its last error. `on_done(key, value)` returns what the Outcome keeps of a result; an
    exception from it stops the run (running tasks are cancelled)."""
    ray = require_ray()
    remote = ray.remote(num_cpus=num_cpus, max_retries=0)(_attempt)
    sink = _sink_class(ray).remote()
    in_flight = in_flight or max(2, 2 * int(ray.cluster_resources().get("CPU", 1)))
    outcomes = {key: Outcome(key) for key, _ in jobs}
    queue = list(enumerate(jobs))
    pending: dict[Any, tuple[int, str, Callable]] = {}
    seen: set = set()

    def submit(i: int, key: str, make: Callable) -> None:
        args, kwargs = make(i)
        outcomes[key].attempts += 1
        ref = remote.remote(fn, key, outcomes[key].attempts, ex.fail_attempts.get(key, 0), sink, args, kwargs)
        pending[ref] = (i, key, make)

    def drain() -> None:
        for key, event_id, payload in ray.get(sink.drain.remote()):
            if (key, event_id) in seen:
                continue
            seen.add((key, event_id))
            if on_event:
                on_event(key, payload)

    try:
        while queue or pending:
            while queue and len(pending) < in_flight:
                i, (key, make) = queue.pop(0)
                submit(i, key, make)
            done, _ = ray.wait(list(pending), num_returns=1, timeout=0.2)
            drain()
            for ref in done:
                i, key, make = pending.pop(ref)
                try:
                    value = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    why = error_text(exc)
                    if outcomes[key].attempts <= ex.retries:
                        if on_retry:
                            on_retry(key, outcomes[key].attempts, why)
                        else:
                            log.warning("%s: attempt %d failed (%s); trying again", key, outcomes[key].attempts, why)
                        submit(i, key, make)
                    else:
                        outcomes[key].error = why
                    continue
                drain()  # this task's last events come before its result is handled
                outcomes[key].value = on_done(key, value) if on_done else value  # what to keep of it
        drain()
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    finally:
        try:
            ray.kill(sink)
        except Exception:  # noqa: BLE001 - the cluster may be going away
            pass
    return outcomes



# -- what every participant task shares (pipeline/ray.py, consolidate/ray.py) -----------------------


def one_thread() -> None:
    """Each task has one CPU: torch and BLAS on one thread, as the local worker processes do."""
    if _PROCESS.get("threads"):
        return
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1)
    except ImportError:
        pass
    import torch

    torch.set_num_threads(1)
    _PROCESS["threads"] = True


def task_embedder(embed_model: str | None):
    """The embedding model, loaded once per worker process; the first task reports the time."""
    import time

    from memora_graph.embed import get_embedder

    t0 = time.perf_counter()
    embedder = get_embedder(embed_model)
    seconds = 0.0
    if not _PROCESS.get("model_loaded"):
        embedder.encode(["warm up"])
        seconds = time.perf_counter() - t0
        _PROCESS["model_loaded"] = True
    return embedder, seconds


def participants_failed(what: str, outcomes: dict, done: list[str]) -> TasksFailed:
    """The error of a run whose participants in `outcomes` failed on every attempt; `done` were
    `what` (built, consolidated) and installed."""
    failed = {k: o.error for k, o in outcomes.items() if o.error}
    lines = "; ".join(f"{k} failed on all {outcomes[k].attempts} attempt(s) ({e})" for k, e in sorted(failed.items()))
    kept = f"the other {len(done)} were {what} and installed" if done else "none was installed"
    return TasksFailed(f"{lines}. {kept}; the failed participant(s) were left as they were in the bank. Re-run "
                       "the same command to try them again.", failed)


def retry_notice(on_notice: Callable[[str], None] | None) -> Callable[[str, int, str], None] | None:
    """`run_tasks`' on_retry that tells `on_notice` of each failed attempt."""
    if on_notice is None:
        return None
    return lambda key, attempt, why: on_notice(f"{key}: attempt {attempt} failed ({why}); trying again")

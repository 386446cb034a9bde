"""The worker-process pool of an annotation build: participants built side by side, one spawned
process each with its own embedding model. The functions handed to the pool stay at module level
(spawned processes import them by name)."""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from memora_graph.bank import Bank
from memora_graph.embed import ThreadGovernor, get_embedder
from memora_graph.pipeline.participant import build_one, BuiltParticipant


def auto_jobs(n_participants: int) -> int:
    """Worker processes for a build: one per core (at most 4), and at least two participants per
    worker, since each worker loads its own embedding model (~8 s here)."""
    return max(1, min(os.cpu_count() or 1, 4, n_participants // 2))



_WORKER: dict = {}


@contextmanager
def interrupts_to_this_process() -> Iterator[None]:
    """Start worker processes inside this block: they never see SIGINT. A Ctrl-C goes to the
    whole process group, and a worker still importing its modules would print a traceback of its
    own; only this process acts on it (it kills the workers, leaves the bank resumable and says so
    in one line). SIGINT is blocked in this thread, and a blocked signal stays blocked across fork
    and exec, so each worker starts with it blocked for life. One that arrives meanwhile (through
    another thread of this process: polars and torch keep their own) is noted, not raised in the
    middle of starting a worker, and raised as KeyboardInterrupt when the block ends; ignoring it,
    as this block once did, dropped a Ctrl-C that landed while a worker started. A no-op off the
    main thread (signals are the main thread's)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    old_handler = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)  # one held for this thread is noted here
        signal.signal(signal.SIGINT, old_handler)
    if held and callable(old_handler):
        old_handler(signal.SIGINT, None)  # Python's own raises KeyboardInterrupt


def _worker_init(embed_model: str | None, events, solo: bool = False) -> None:
    """Runs once in each worker process: die with the parent (a killed build must not leave
    workers writing), one thread for torch and BLAS (unless it is the only worker), then load
    the embedding model."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG (Linux)
    except (OSError, AttributeError):
        pass
    if not solo:
        try:
            from threadpoolctl import threadpool_limits

            threadpool_limits(limits=1)
        except ImportError:
            pass
    _WORKER["events"] = events
    _WORKER["solo"] = solo
    t0 = time.perf_counter()
    try:
        import torch

        if not solo:
            torch.set_num_threads(1)
        _WORKER["embedder"] = get_embedder(embed_model)
    except Exception as exc:  # noqa: BLE001 - raised again, as itself, by the first task
        _WORKER["error"] = exc
    _WORKER["model_seconds"] = time.perf_counter() - t0


def _worker_model() -> str:
    if "error" in _WORKER:
        raise _WORKER["error"]
    return _WORKER["embedder"].name


def _worker_build(bank_path: str, p: str, actions, durations: dict, classes, opts: dict) -> BuiltParticipant:
    _worker_model()
    events = _WORKER["events"]
    governor = ThreadGovernor() if _WORKER.get("solo") else ThreadGovernor(max_threads=1)
    r = build_one(Bank(bank_path), p, actions, durations, classes, _WORKER["embedder"], governor,
                   on_video=lambda v, n: events.put((p, v, n)), **opts)
    r.model_seconds = _WORKER.pop("model_seconds", 0.0)  # reported by a worker's first participant
    return r


def build_parallel(bank: Bank, found: list[str], df, durations: dict, classes, embed_model: str | None, jobs: int,
                    on_video, opts: dict, results: list[BuiltParticipant] | None = None) -> list[BuiltParticipant]:
    """Build participants in `jobs` worker processes; `results` receives each finished one as
    it arrives. When one fails, the others are stopped at once (killed: a worker stuck in a
    Kùzu call cannot be asked) and the failure is raised."""
    import multiprocessing
    import queue
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    ctx = multiprocessing.get_context("spawn")  # a fresh interpreter: no forked torch / Kùzu threads
    # workers stopped at once are killed (below): the semaphores they held are unlinked by
    # multiprocessing's resource tracker, which then warns of each at exit; that is expected here,
    # so the tracker (started with this interpreter's -W options) is told not to say so
    quiet = "ignore:resource_tracker:UserWarning"
    if quiet not in sys.warnoptions:
        sys.warnoptions.append(quiet)
    events = ctx.Queue()

    def drain() -> None:
        while True:
            try:
                p, v, n = events.get_nowait()
            except queue.Empty:
                return
            if on_video:
                on_video(p, v, n)

    sizes = df.group_by("participant_id").len().iter_rows()
    order = [p for p, _ in sorted(sizes, key=lambda r: (-r[1], r[0]))]  # largest first: the last to finish is small
    finished: dict[str, BuiltParticipant] = {}
    results = results if results is not None else []
    pool = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_worker_init,
                               initargs=(embed_model, events, jobs == 1))
    try:
        # every worker starts and loads its model at once; the model loads (or says why it
        # cannot) before the bank is touched
        with interrupts_to_this_process():  # each submit starts a worker (spawn starts them on demand)
            probes = [pool.submit(_worker_model) for _ in range(jobs)]
        name = probes[0].result()
        bank.init(mode=opts["mode"], embed_model=name, consolidated=False)
        futures = {}
        for p in order:
            actions = df.filter(df["participant_id"] == p)
            videos = set(actions["video_id"].unique().to_list())
            futures[pool.submit(_worker_build, str(bank.path), p, actions,
                                {v: d for v, d in durations.items() if v in videos}, classes, opts)] = p
        pending = set(futures)
        while pending:
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            drain()
            for f in sorted(done, key=lambda f: futures[f]):
                exc = f.exception()
                if exc is None:
                    finished[futures[f]] = f.result()
                    results.append(finished[futures[f]])
            for f in done:
                if f.exception() is not None:
                    raise f.exception()
        drain()
    except BaseException:
        # ProcessPoolExecutor has no public way to stop a running task: kill its processes
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            proc.kill()
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    return [finished[p] for p in found]

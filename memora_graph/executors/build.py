"""Builds and consolidation on Ray: one task per participant.

Each task unpacks the participant's snapshot into the worker's scratch space, runs the same
library code a local build runs there (`pipeline.participant._build_one`, `build_from_video`,
`finish_participant`), and hands back the closed database with the manifest entry it recorded
(`bundle.seal`). The driver installs each one as it arrives (`bundle.install`), holding every
planned participant's build lock for the whole run, so no other build can touch them meanwhile.
A participant that fails on every attempt is left as it was in the bank and reported
(`TasksFailed`); the others are installed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import ExitStack

from memora_graph.bank import Bank
from memora_graph.executors import Executor, TasksFailed, bundle
from memora_graph.executors.tasks import cluster, run_tasks

_PROCESS: dict = {}  # per worker process: whether threads were limited, model load time not yet reported


def _one_thread() -> None:
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


def _embedder(embed_model: str | None):
    """The embedding model, loaded once per worker process; the first task reports the time."""
    from memora_graph.embed import get_embedder

    t0 = time.perf_counter()
    embedder = get_embedder(embed_model)
    seconds = 0.0
    if not _PROCESS.get("model_loaded"):
        embedder.encode(["warm up"])
        seconds = time.perf_counter() - t0
        _PROCESS["model_loaded"] = True
    return embedder, seconds


def _failure(what: str, outcomes: dict, done: list[str]) -> TasksFailed:
    failed = {k: o.error for k, o in outcomes.items() if o.error}
    lines = "; ".join(f"{k} failed on all {outcomes[k].attempts} attempt(s) ({e})" for k, e in sorted(failed.items()))
    kept = f"the other {len(done)} were {what} and installed" if done else "none was installed"
    return TasksFailed(f"{lines}. {kept}; the failed participant(s) were left as they were in the bank. Re-run "
                       "the same command to try them again.", failed)


# -- annotation builds ---------------------------------------------------------------------------


def build_task(snap: dict, actions, durations: dict, classes, opts: dict, embed_model: str | None,
               shared: str | None, *, progress: Callable) -> dict:
    """On a worker: build one participant in scratch space; its sealed database and _Built."""
    from memora_graph.embed import ThreadGovernor
    from memora_graph.pipeline.participant import _build_one

    p = snap["participant"]
    scratch = bundle.open_scratch(snap)
    try:
        _one_thread()
        embedder, model_seconds = _embedder(embed_model)
        built = _build_one(scratch, p, actions, durations, classes, embedder, ThreadGovernor(max_threads=1),
                           on_video=lambda v, n: progress(v, (p, v, n)), **opts)
        built.model_seconds = model_seconds
        return {**bundle.seal(scratch, p, shared), "result": built}
    finally:
        bundle.remove_scratch(scratch)


def build_on_ray(ex: Executor, bank: Bank, found: list[str], df, durations: dict, classes, embed_model: str | None,
                 on_video, opts: dict, results: list, on_notice: Callable[[str], None] | None = None) -> list:
    """The Ray side of `build_bank`: every participant of `found` built by a task and installed
    here; `results` receives each _Built as it is installed. Raises TasksFailed naming the
    participants that failed on every attempt (after installing the others)."""
    from memora_graph.embed import get_embedder

    bank.init(mode=opts["mode"], embed_model=get_embedder(embed_model).name, consolidated=False)
    sizes = dict(df.group_by("participant_id").len().iter_rows())
    order = sorted(found, key=lambda p: (-sizes.get(p, 0), p))  # largest first: the last to finish is small
    with cluster(ex) as ray, ExitStack() as locks:
        for p in found:
            locks.enter_context(bank.participant_lock(p))
            bank.check_before_build(p)
        classes_ref = ray.put(classes)

        def make(p: str) -> Callable:
            def args(i: int):
                actions = df.filter(df["participant_id"] == p)
                videos = set(actions["video_id"].unique().to_list())
                return (bundle.snapshot(bank, p), actions, {v: d for v, d in durations.items() if v in videos},
                        classes_ref, opts, embed_model, ex.shared), {}
            return args

        def done(p: str, value: dict):
            bundle.install(bank, p, value)
            results.append(value["result"])
            return value["result"]

        outcomes = run_tasks(ex, build_task, [(p, make(p)) for p in order], on_done=done,
                             on_event=(lambda key, ev: on_video(*ev)) if on_video else None,
                             on_retry=_retry_notice(on_notice))
    ok = [p for p in found if outcomes[p].error is None]
    if len(ok) < len(found):
        raise _failure("built", outcomes, ok)
    return [outcomes[p].value for p in found]


def _retry_notice(on_notice):
    if on_notice is None:
        return None
    return lambda key, attempt, why: on_notice(f"{key}: attempt {attempt} failed ({why}); trying again")


# -- video builds -----------------------------------------------------------------------------------


def video_task(snap: dict, video: str, kwargs: dict, shared: str | None, *, progress: Callable) -> dict:
    """On a worker: one participant's videos, in order, into scratch space."""
    from memora_graph.pipeline import build_from_video

    p = snap["participant"]
    scratch = bundle.open_scratch(snap)
    try:
        _one_thread()
        res = build_from_video(scratch.path, video, p, **kwargs,
                               on_video=lambda v, n: progress(f"v:{v}", ("video", p, v, n)),
                               on_segment=lambda v, t, err: progress(f"s:{v}:{t}", ("segment", p, v, err)))
        return {**bundle.seal(scratch, p, shared), "result": res}
    finally:
        bundle.remove_scratch(scratch)


def video_on_ray(ex: Executor, bank: Bank, jobs: list[tuple[str, str]], kwargs: dict,
                 on_event: Callable[[tuple], None] | None = None,
                 on_notice: Callable[[str], None] | None = None) -> list:
    """Video builds, one task per (participant, video file or directory); task i talks to
    `ex.base_url(i)` when several servers are given. Returns each participant's VideoBuild, in
    the order of `jobs`. Raises TasksFailed after installing the others."""
    from memora_graph.embed import get_embedder

    bank.path.mkdir(parents=True, exist_ok=True)
    bank.init(mode="edited", embed_model=get_embedder(kwargs.get("embed_model")).name, consolidated=False)
    with cluster(ex), ExitStack() as locks:
        for p, _ in jobs:
            locks.enter_context(bank.participant_lock(p))
            bank.check_before_build(p)

        def make(p: str, video: str) -> Callable:
            def args(i: int):
                kw = dict(kwargs)
                if ex.base_urls:
                    kw["base_url"] = ex.base_url(i)
                return (bundle.snapshot(bank, p), video, kw, ex.shared), {}
            return args

        def done(p: str, value: dict):
            bundle.install(bank, p, value)
            return value["result"]

        outcomes = run_tasks(ex, video_task, [(p, make(p, v)) for p, v in jobs], on_done=done,
                             on_event=(lambda key, ev: on_event(ev)) if on_event else None,
                             on_retry=_retry_notice(on_notice))
    ok = [p for p, _ in jobs if outcomes[p].error is None]
    if len(ok) < len(jobs):
        raise _failure("built", outcomes, ok)
    return [outcomes[p].value for p, _ in jobs]


# -- consolidation -----------------------------------------------------------------------------------


def consolidate_task(snap: dict, processor: str, options: dict | None, embed_model: str, shared: str | None, *,
                     progress: Callable) -> dict:
    """On a worker: `memora consolidate` of one participant in scratch space. A participant whose
    every model step failed comes back too (its failed calls are recorded in it, as locally)."""
    from memora_graph.consolidate import finish_participant, get_processors
    from memora_graph.errors import ConsolidationError

    p = snap["participant"]
    scratch = bundle.open_scratch(snap)
    try:
        _one_thread()
        embedder, _ = _embedder(embed_model)
        opts = dict(options or {}, on_step=lambda part, step: progress(f"step:{step}", (part, step))) \
            if options is not None else None
        procs = get_processors(processor, options=opts)
        t0 = time.perf_counter()
        row: dict = {"participant": p, "processor": procs.name}
        failed: list[str] = []
        try:
            knowledge = finish_participant(scratch, p, embedder, processors=procs)
        except ConsolidationError as exc:
            failed.append(str(exc))
            row.update(routines=None, preferences=None, dropped_ids=None, dropped_records=None, model_calls=None,
                       failed_steps=None, status="unchanged (every model step failed)")
        else:
            row.update(routines=len(knowledge.routines), preferences=len(knowledge.preferences),
                       dropped_ids=knowledge.dropped_ids, dropped_records=knowledge.dropped_records,
                       model_calls=len(knowledge.calls), failed_steps=len(knowledge.failed_steps),
                       status="consolidated")
            failed += [f"{p} {s.step}: {s.error}" for s in knowledge.failed_steps]
        row["seconds"] = round(time.perf_counter() - t0, 1)
        calls = list(procs.call_log.records) if procs.call_log is not None else []
        return {**bundle.seal(scratch, p, shared), "result": (row, failed, calls)}
    finally:
        bundle.remove_scratch(scratch)


def consolidate_on_ray(ex: Executor, bank: Bank, pids: list[str], processor: str, options: dict | None,
                       on_participant: Callable[[str], None] | None = None,
                       on_step: Callable[[str, str], None] | None = None,
                       on_notice: Callable[[str], None] | None = None) -> list[tuple[dict, list[str], list]]:
    """`memora consolidate` with one task per participant; (row, failure lines, model calls) per
    participant in the order of `pids`. `options`: the llm processor's options without `on_step`
    (task i talks to `ex.base_url(i)` when several servers are given)."""
    embed_model = bank.manifest()["embed_model"]
    with cluster(ex), ExitStack() as locks:
        for p in pids:
            locks.enter_context(bank.participant_lock(p))

        def make(p: str) -> Callable:
            def args(i: int):
                opts = dict(options) if options is not None else None
                if opts is not None and ex.base_urls:
                    opts["base_url"] = ex.base_url(i)
                return (bundle.snapshot(bank, p), processor, opts, embed_model, ex.shared), {}
            return args

        def done(p: str, value: dict):
            bundle.install(bank, p, value)
            if on_participant:
                on_participant(p)
            return value["result"]

        outcomes = run_tasks(ex, consolidate_task, [(p, make(p)) for p in pids], on_done=done,
                             on_event=(lambda key, ev: on_step(*ev)) if on_step else None,
                             on_retry=_retry_notice(on_notice))
    ok = [p for p in pids if outcomes[p].error is None]
    if len(ok) < len(pids):
        raise _failure("consolidated", outcomes, ok)
    return [outcomes[p].value for p in pids]

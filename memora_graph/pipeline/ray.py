"""Builds on Ray: one task per participant (annotation builds) or per participant's videos.

Each task unpacks the participant's snapshot into the worker's scratch space, runs the same
library code a local build runs there (`pipeline.participant.build_one`, `build_from_video`),
and hands back the closed database with the manifest entry it recorded (`bundle.seal`). The
driver installs each one as it arrives (`bundle.install`), holding every planned participant's
build lock for the whole run, so no other build can touch them meanwhile. A participant that
fails on every attempt is left as it was in the bank and reported (`TasksFailed`); the others
are installed. Consolidation on Ray lives beside consolidation (consolidate/ray.py).
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack

from memora_graph.bank import Bank
from memora_graph.executors import Executor, bundle
from memora_graph.executors.tasks import cluster, one_thread, participants_failed, retry_notice, run_tasks, \
    task_embedder


# -- annotation builds ---------------------------------------------------------------------------


def build_task(snap: dict, actions, durations: dict, classes, opts: dict, embed_model: str | None,
               shared: str | None, *, progress: Callable) -> dict:
    """On a worker: build one participant in scratch space; its sealed database and BuiltParticipant."""
    from memora_graph.embed import ThreadGovernor
    from memora_graph.pipeline.participant import build_one

    p = snap["participant"]
    scratch = bundle.open_scratch(snap)
    try:
        one_thread()
        embedder, model_seconds = task_embedder(embed_model)
        built = build_one(scratch, p, actions, durations, classes, embedder, ThreadGovernor(max_threads=1),
                           on_video=lambda v, n: progress(v, (p, v, n)), **opts)
        built.model_seconds = model_seconds
        return {**bundle.seal(scratch, p, shared), "result": built}
    finally:
        bundle.remove_scratch(scratch)


def build_on_ray(ex: Executor, bank: Bank, found: list[str], df, durations: dict, classes, embed_model: str | None,
                 on_video, opts: dict, results: list, on_notice: Callable[[str], None] | None = None) -> list:
    """The Ray side of `build_bank`: every participant of `found` built by a task and installed
    here; `results` receives each BuiltParticipant as it is installed. Raises TasksFailed naming the
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
                             on_retry=retry_notice(on_notice))
    ok = [p for p in found if outcomes[p].error is None]
    if len(ok) < len(found):
        raise participants_failed("built", outcomes, ok)
    return [outcomes[p].value for p in found]


# -- video builds -----------------------------------------------------------------------------------


def video_task(snap: dict, video: str, kwargs: dict, shared: str | None, *, progress: Callable) -> dict:
    """On a worker: one participant's videos, in order, into scratch space."""
    from memora_graph.pipeline.video import build_from_video

    p = snap["participant"]
    scratch = bundle.open_scratch(snap)
    try:
        one_thread()
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
                             on_retry=retry_notice(on_notice))
    ok = [p for p, _ in jobs if outcomes[p].error is None]
    if len(ok) < len(jobs):
        raise participants_failed("built", outcomes, ok)
    return [outcomes[p].value for p, _ in jobs]

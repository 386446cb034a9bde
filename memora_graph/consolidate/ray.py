"""Consolidation on Ray (`memora consolidate --executor ray`): one task per participant.

Each task unpacks the participant's snapshot into the worker's scratch space, runs
`finish_participant` there with the named processors, and hands back the closed database with
the manifest entry it recorded (`bundle.seal`); the driver installs each one as it arrives
(`bundle.install`), holding every participant's lock for the whole run. A participant that fails
on every attempt is left as it was in the bank and reported (`TasksFailed`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import ExitStack

from memora_graph.bank import Bank
from memora_graph.executors import Executor, bundle
from memora_graph.executors.tasks import cluster, one_thread, participants_failed, retry_notice, run_tasks, \
    task_embedder


def consolidate_task(snap: dict, processor: str, options: dict | None, embed_model: str, shared: str | None, *,
                     progress: Callable) -> dict:
    """On a worker: `memora consolidate` of one participant in scratch space. A participant whose
    every model step failed comes back too (its failed calls are recorded in it, as locally)."""
    from memora_graph.consolidate.processors import get_processors
    from memora_graph.consolidate.run import finish_participant
    from memora_graph.errors import ConsolidationError

    p = snap["participant"]
    scratch = bundle.open_scratch(snap)
    try:
        one_thread()
        embedder, _ = task_embedder(embed_model)
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
                             on_retry=retry_notice(on_notice))
    ok = [p for p in pids if outcomes[p].error is None]
    if len(ok) < len(pids):
        raise participants_failed("consolidated", outcomes, ok)
    return [outcomes[p].value for p in pids]

"""Evaluations on Ray: one task per (condition, participant) shard.

A task runs the shard's items with the runner's own code (`items.run_plan`, so each record
is what a local run writes) into a scratch run folder, and hands back the records files and its
model calls. The driver appends them to the run folder as each shard arrives (a killed driver
keeps the shards it merged; a re-run skips their `ok` items, as a local run does). Items already
recorded `ok` are not sent. The banks are read where they are: every node must see them at the
same path (a shared filesystem), as a local instance does.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from memora_graph.bench.conditions import BankSet, get_condition
from memora_graph.bench.items import KINDS, RunSummary, make_policy, one_torch_thread, read_records, record_path, \
    run_plan
from memora_graph.executors import Executor, TasksFailed
from memora_graph.executors.tasks import cluster, run_tasks

_POLICIES: dict = {}  # offline readers, one per worker process


def shard_task(banks: BankSet, condition: str, kinds: tuple[str, ...], plan: list, memories: dict, backend: str,
               options: dict, *, progress: Callable) -> dict:
    """On a worker: one (condition, participant) shard into a scratch run folder."""
    scratch = Path(tempfile.mkdtemp(prefix="memora-shard-"))
    try:
        if backend == "offline":
            policy = _POLICIES.get("offline") or _POLICIES.setdefault("offline", make_policy(backend, options, scratch))
        else:
            policy = make_policy(backend, options, scratch)  # its calls go to scratch/model_calls.jsonl
        summary = RunSummary(scratch)
        t0 = time.perf_counter()
        with one_torch_thread():
            run_plan(scratch, banks, [get_condition(condition)], kinds, plan, memories, policy, summary,
                      lambda rec: progress(rec["item_id"], {k: rec.get(k) for k in ("condition", "item_id", "status")}))
        files = {}
        for kind in kinds:
            path = record_path(scratch, kind, condition)
            if path.exists():
                files[str(path.relative_to(scratch))] = path.read_text(encoding="utf-8")
        calls = scratch / "model_calls.jsonl"
        return {"files": files, "calls": calls.read_text(encoding="utf-8") if calls.exists() else "",
                "done": summary.done, "failed": summary.failed, "seconds": time.perf_counter() - t0}
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def run_shards_on_ray(ex: Executor, out: Path, banks: BankSet, conds: list, kinds: tuple[str, ...], plan: list,
                      memories: dict, backend: str, options: dict[str, Any], summary: RunSummary,
                      on_item: Callable[[dict], None] | None = None,
                      on_notice: Callable[[str], None] | None = None) -> None:
    """The Ray side of `run_bench`: what `run_plan` would do for `conds` x `plan`, as shards."""
    banks = BankSet(edited=Path(banks.edited).resolve(), raw=Path(banks.raw).resolve() if banks.raw else None,
                    episodic=Path(banks.episodic).resolve() if banks.episodic else None)
    jobs = []
    for cond in conds:
        existing = {kind: read_records(record_path(out, kind, cond.name)) for kind in KINDS}
        for pid in dict.fromkeys(p for p, _, _ in plan):
            shard = []
            for p, kind, item in plan:
                if p != pid or kind not in kinds:
                    continue
                item_id = item.question_id if kind == "eam_qa" else item.task_id
                if existing[kind].get(item_id, {}).get("status") == "ok":
                    summary.skipped += 1
                    if on_item:
                        on_item({"condition": cond.name, "item_id": item_id, "status": "skipped"})
                    continue
                shard.append((p, kind, item))
            if shard:
                jobs.append((f"{cond.name}/{pid}", _make(ex, banks, cond.name, kinds, shard, {pid: memories[pid]},
                                                         backend, options)))

    def done(key: str, value: dict):
        for rel, text in sorted(value["files"].items()):
            path = out / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            with path.open("a", encoding="utf-8") as fh:
                fh.write(text)
        if value["calls"]:
            with (out / "model_calls.jsonl").open("a", encoding="utf-8") as fh:
                fh.write(value["calls"])
        summary.done += value["done"]
        summary.failed += value["failed"]
        cond = key.split("/", 1)[0]
        summary.per_condition_seconds[cond] = summary.per_condition_seconds.get(cond, 0.0) + value["seconds"]
        return None

    if not jobs:
        return
    with cluster(ex):
        outcomes = run_tasks(ex, shard_task, jobs, on_done=done,
                             on_event=(lambda key, rec: on_item(rec)) if on_item else None,
                             on_retry=(lambda key, n, why: on_notice(f"{key}: attempt {n} failed ({why}); trying again"))
                             if on_notice else None)
    failed = {k: o.error for k, o in outcomes.items() if o.error}
    if failed:
        lines = "; ".join(f"shard {k} failed on all {outcomes[k].attempts} attempt(s) ({e})"
                          for k, e in sorted(failed.items()))
        raise TasksFailed(f"{lines}. The other shards' records were merged into {out}; re-run the same command to "
                          "run the failed shards' items.", failed)


def _make(ex: Executor, banks: BankSet, condition: str, kinds, shard: list, memories: dict, backend: str,
          options: dict) -> Callable:
    def args(i: int):
        opts = dict(options)
        if ex.base_urls and backend != "offline":
            opts["base_url"] = ex.base_url(i)
        return (banks, condition, tuple(kinds), shard, memories, backend, opts), {}
    return args

"""The runner: conditions x tasks, one agent episode per item, one JSON line per item.

    run_bench(bank, out, conditions="all", participants=["P01"], backend="offline")

Layout of a run directory:
    manifest.json                 code version, backend, model, options, seeds, task-set hash, banks
    records/eam_qa/<condition>.jsonl
    records/planning/<condition>.jsonl   (Replay and Generalize; `split` says which)
    scoring_memory/<PID>.json     the MEMORA-full routines, preferences and object names the
                                  planning metrics read (the paper scores every condition against it)
    memory_formation/<PID>.json   the MEMORA bank's records per segment with and without the editor,
                                  and its decision counts (the report's compression / decision figures)
    results.parquet               one row per item (the latest record of each), written at the end
    model_calls.jsonl             one line per model call (model backends only)

Model backends run `concurrency` agent loops at once (default 32; threads, each loop unchanged):
records are written in the order a `--concurrency 1` run writes them, with the same content
except timings. Memory tools run one at a time under a lock (Kùzu connections and the query
encoder are shared); the model calls overlap.

Resumable: an item with an `ok` record is not run again; a failed one is retried (the loader keeps
the last record of each item). One failing item is recorded as failed and never stops the run.
Under the offline backend the run is deterministic.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import polars as pl

from memora_graph.agent.policies import is_model_policy
from memora_graph.agent.prompts import PROMPT_VERSION
from memora_graph.bank import Bank
from memora_graph.bench.conditions import BankSet, Condition, resolve_conditions
from memora_graph.bench.items import (
    DEFAULT_TEMPERATURE, KINDS, RunSummary, make_policy, one_torch_thread, read_records, record_path, run_item, run_plan,
)
from memora_graph.bench.tasks import BenchSuite, load_suite
from memora_graph.consolidate.task_records import TASK_SOURCES
from memora_graph.errors import MemoraError
from memora_graph.stats import memory_formation

RUN_FORMAT = 1
DEFAULT_CONCURRENCY = 32  # agent loops in flight against a model server


# -- run directory ------------------------------------------------------------------------------


def load_run(out: str | Path) -> dict[str, dict[str, list[dict]]]:
    """{"eam_qa"|"planning": {condition: [records]}} of a run directory."""
    out = Path(out)
    result: dict[str, dict[str, list[dict]]] = {"eam_qa": {}, "planning": {}}
    for kind in result:
        folder = out / "records" / kind
        for path in sorted(folder.glob("*.jsonl")) if folder.is_dir() else []:
            result[kind][path.stem] = list(read_records(path).values())
    return result


def _code_version() -> str:
    try:
        from importlib.metadata import version

        pkg = version("memora-graph")
    except Exception:
        pkg = "unknown"
    try:
        sha = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent).stdout.strip()
    except Exception:
        sha = ""
    return f"{pkg}+{sha}" if sha else pkg


def task_set_hash(suite: BenchSuite) -> str:
    h = hashlib.sha256()
    for pid, entry in suite.participants.items():
        h.update(pid.encode())
        for q in (entry.eam_qa.questions if entry.eam_qa else []):
            h.update(q.model_dump_json().encode())
        for t in [*(entry.replay or []), *(entry.generalize or [])]:
            h.update(t.model_dump_json().encode())
    return h.hexdigest()[:16]


def scoring_memory(bank: Path, participant: str) -> dict[str, Any]:
    """What the planning metrics read from the participant's MEMORA bank (routines, preferences,
    object names); stored in the run so the report needs only the run directory. The task memory's
    records (how tasks are done: sources in TASK_SOURCES) are left out: they are what a memory
    offers a planner, not the yardstick it is scored against, which stays the one every earlier run
    was scored with."""
    with Bank(bank).open(participant) as store:
        routines = [r for r in store.rows("_baseline_routines_all", participant=participant)
                    if r.get("source") not in TASK_SOURCES]
        prefs = [p for p in store.rows("_baseline_preferences_all", participant=participant)
                 if p.get("source") not in TASK_SOURCES]
        objects = store.rows("_baseline_entities_all", participant=participant)
    return {
        "routines": [{"goal": r["goal"], "canonical_steps": [{"action": s} for s in r["canonical_steps"] or []],
                      "key_objects": [{"object": o} for o in r["key_objects"] or []]} for r in routines],
        "preferences": [{"preference": p["statement"], "keywords": list(p["keywords"] or [])} for p in prefs],
        "object_names": sorted({o["name"] for o in objects if o["name"]}),
        "places": sorted({(o["location"] or "").replace("_", " ") for o in objects if o["location"]}),
    }


# -- the run ----------------------------------------------------------------------------------------


def run_bench(
    bank: str | Path,
    out: str | Path,
    *,
    conditions: str | list[str] | None = "all",
    participants: list[str] | None = None,
    tasks: str | Path | None = None,
    raw_bank: str | Path | None = None,
    episodic_bank: str | Path | None = None,
    backend: str = "offline",
    backend_options: dict[str, Any] | None = None,
    kinds: tuple[str, ...] = KINDS,
    limit: int | None = None,
    on_item: Callable[[dict[str, Any]], None] | None = None,
    on_plan: Callable[[int], None] | None = None,
    workers: int | None = None,
    concurrency: int | None = None,
    executor=None,
) -> RunSummary:
    """Run every (condition, item) not yet recorded in `out`. `limit` caps items per participant
    and task kind (for smoke runs). `workers` > 1 runs the conditions in that many processes
    (default: 2 under `offline` on a machine with 2+ cores, else 1); results do not depend on it.
    `concurrency` is the number of agent loops in flight for model backends (default 32); records
    do not depend on it either (content and order, timings aside). `executor`
    (memora_graph.executors.Executor) 'ray' runs one task per (condition, participant) shard
    instead (bench/ray.py); the records are the same."""
    t_start = time.perf_counter()
    concurrency = resolve_concurrency(concurrency, backend)  # a bad value fails before anything is written
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or not kinds:
        raise MemoraError(f"--kinds: unknown task kind(s) {', '.join(unknown) or '(none given)'}; "
                          f"choose from {', '.join(KINDS)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    bank = Path(bank)
    conds = resolve_conditions(conditions)
    suite = load_suite(tasks, participants)
    known = set(Bank(bank).participants())
    missing = sorted(set(suite.participants) - known)
    if missing:
        raise MemoraError(f"{bank}: no memory for participant(s) {', '.join(missing)}; build them first "
                          f"(`memora build {bank} --participants {','.join(missing)}`) or pass --participants")
    if any(c.bank == "raw" for c in conds) and raw_bank is None:
        raise MemoraError("the raw conditions (flat_1d_raw, graph_2d_raw) need --raw-bank DIR, a bank built with "
                          "`memora build DIR --mode raw`; or leave them out with --conditions")
    if any(c.bank == "episodic" for c in conds) and episodic_bank is None:
        raise MemoraError("memora_episodic needs --episodic-bank DIR, a bank built with `memora build DIR --episodic`; "
                          "or leave it out with --conditions")
    banks = BankSet(edited=bank, raw=Path(raw_bank) if raw_bank else None,
                    episodic=Path(episodic_bank) if episodic_bank else None)
    workers = resolve_workers(workers, backend, len(conds))
    # under parallel offline workers each process loads its own reader; the parent needs none
    policy = None if workers > 1 and not is_model_policy(backend) else make_policy(backend, backend_options or {}, out)
    _write_manifest(out, bank, raw_bank, episodic_bank, conds, suite, tasks, backend, backend_options or {}, policy, kinds, limit,
                    workers, concurrency)
    plan: list[tuple[str, str, Any]] = []
    for pid, entry in suite.participants.items():
        items = {"eam_qa": entry.eam_qa.questions if entry.eam_qa else [], "replay": entry.replay or [],
                 "generalize": entry.generalize or []}
        for kind in kinds:
            for it in items[kind][:limit] if limit else items[kind]:
                plan.append((pid, kind, it))
    summary = RunSummary(out)
    if on_plan:
        on_plan(len(plan) * len(conds))
    memories = {}
    for pid in suite.participants:  # what the metrics read, saved with the run (the report reads only the run)
        memories[pid] = scoring_memory(bank, pid)
        _write_json(out / "scoring_memory" / f"{pid}.json", memories[pid], indent=1)
        _write_json(out / "memory_formation" / f"{pid}.json", memory_formation(bank, pid))
    t_items = time.perf_counter()
    if executor is not None and executor.remote:
        from memora_graph.bench.ray import run_shards_on_ray

        run_shards_on_ray(executor, out, banks, conds, kinds, plan, memories, backend, backend_options or {}, summary,
                          on_item)
    elif workers > 1:
        _run_parallel(workers, out, banks, conds, kinds, plan, memories, backend, backend_options or {}, summary, on_item)
    elif concurrency > 1:
        with one_torch_thread():
            _run_plan_concurrent(out, banks, conds, kinds, plan, memories, policy, summary, on_item, concurrency)
    else:
        with one_torch_thread():
            run_plan(out, banks, conds, kinds, plan, memories, policy, summary, on_item)
    summary.items_seconds = time.perf_counter() - t_items
    write_results_table(out)
    summary.seconds = time.perf_counter() - t_start
    manifest = json.loads((out / "manifest.json").read_text())
    manifest.setdefault("sessions", []).append({
        "finished_at": _now(), "seconds": round(summary.seconds, 2), "done": summary.done,
        "skipped": summary.skipped, "failed": summary.failed,
        "per_condition_seconds": {k: round(v, 2) for k, v in summary.per_condition_seconds.items()},
    })
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2))
    return summary


def _write_json(path: Path, data: Any, indent: int | None = None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=indent))
    os.replace(tmp, path)


# relative cost of one item per condition under `offline` (Parametric reads no memory)
_COST = {"no_memory": 0.15}


def resolve_workers(workers: int | None, backend: str, n_conditions: int) -> int:
    """Worker processes for a run: given, or by default one per core up to 2 under `offline` (the
    reader is CPU-bound) and 1 for model backends (the server sets the pace)."""
    if workers is None:
        workers = min(2, os.cpu_count() or 1) if not is_model_policy(backend) else 1
    if workers < 1:
        raise MemoraError(f"--workers must be at least 1, got {workers}")
    return max(1, min(workers, n_conditions))


def resolve_concurrency(concurrency: int | None, backend: str) -> int:
    """Agent loops in flight: given, or 32 for model backends; the offline policy runs one at a
    time per worker process (it is CPU-bound, so threads would only take turns)."""
    if concurrency is None:
        return 1 if backend == "offline" else DEFAULT_CONCURRENCY
    if concurrency < 1:
        raise MemoraError(f"--concurrency must be at least 1, got {concurrency}")
    return 1 if backend == "offline" else concurrency


def split_conditions(conds: list[Condition], workers: int) -> list[list[Condition]]:
    """Conditions dealt to workers, heaviest first to the least-loaded worker; each condition runs
    whole in one worker, so each records file has one writer."""
    groups: list[list[Condition]] = [[] for _ in range(workers)]
    load = [0.0] * workers
    for c in sorted(conds, key=lambda c: -_COST.get(c.name, 1.0)):
        i = min(range(workers), key=lambda j: (load[j], j))
        groups[i].append(c)
        load[i] += _COST.get(c.name, 1.0)
    return [g for g in groups if g]


def _worker(args: dict[str, Any]) -> dict[str, Any]:
    """One worker process: its conditions over the whole plan; progress goes back on a queue."""
    from memora_graph.bench.conditions import get_condition

    queue = args.pop("queue")
    policy = make_policy(args["backend"], args["backend_options"], args["out"])
    summary = RunSummary(args["out"])
    conds = [get_condition(n) for n in args["conditions"]]
    with one_torch_thread():
        run_plan(args["out"], args["banks"], conds, args["kinds"], args["plan"], args["memories"], policy, summary,
                  lambda rec: queue.put({k: rec.get(k) for k in ("condition", "item_id", "status")}))
    return {"done": summary.done, "skipped": summary.skipped, "failed": summary.failed,
            "per_condition_seconds": summary.per_condition_seconds}


def _run_parallel(workers, out, banks, conds, kinds, plan, memories, backend, options, summary, on_item) -> None:
    import multiprocessing as mp
    import queue as queue_mod
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    ctx = mp.get_context("spawn")  # a fresh interpreter: no torch or Kùzu state crosses a fork
    with ctx.Manager() as manager:
        q = manager.Queue()
        banks = BankSet(edited=banks.edited, raw=banks.raw, episodic=banks.episodic)
        jobs = [{"queue": q, "out": out, "banks": banks, "conditions": [c.name for c in group], "kinds": kinds,
                 "plan": plan, "memories": memories, "backend": backend, "backend_options": options}
                for group in split_conditions(conds, workers)]
        with ProcessPoolExecutor(max_workers=len(jobs), mp_context=ctx) as pool:
            pending = {pool.submit(_worker, job) for job in jobs}
            while pending:
                done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                _drain(q, on_item, queue_mod)
                for fut in done:
                    res = fut.result()  # a worker that crashed outright stops the run with its error
                    summary.done += res["done"]
                    summary.skipped += res["skipped"]
                    summary.failed += res["failed"]
                    summary.per_condition_seconds.update(res["per_condition_seconds"])
            _drain(q, on_item, queue_mod)


def _drain(q, on_item, queue_mod) -> None:
    while True:
        try:
            rec = q.get_nowait()
        except queue_mod.Empty:
            return
        if on_item:
            on_item(rec)


class _LockedTools:
    """A condition's tool set whose calls run one at a time (shared Kùzu connections, encoder)."""

    def __init__(self, toolset, lock):
        self._toolset, self._lock = toolset, lock
        self.participant = toolset.participant

    def schemas(self):
        return self._toolset.schemas()

    def call(self, name, arguments):
        with self._lock:
            return self._toolset.call(name, arguments)

    def prefetch(self, calls):
        prefetch = getattr(self._toolset, "prefetch", None)
        if prefetch is not None:
            with self._lock:
                prefetch(calls)


class _SharedBanks:
    """The run's BankSet for many threads: memories load once under a lock, stay open while any
    item of their participant is still to run, and are closed when its last item is done."""

    def __init__(self, banks: BankSet):
        import threading

        self._banks = banks
        self._lock = threading.Lock()
        self.tool_lock = threading.RLock()
        self._memories: dict[tuple[str, str], Any] = {}

    def path(self, kind: str) -> Path:
        return self._banks.path(kind)

    def memory(self, key: str, participant: str, loader: Callable[[], Any]) -> Any:
        with self._lock:
            k = (key, participant)
            if k not in self._memories:
                with self.tool_lock:
                    self._memories[k] = loader()
            return self._memories[k]

    def release(self, participant: str) -> None:
        with self._lock:
            for k in [k for k in self._memories if k[1] == participant]:
                closer = getattr(self._memories.pop(k), "close", None)
                if closer:
                    with self.tool_lock:
                        closer()


class _LockedCondition:
    """A condition whose tools come from the shared banks, behind the tool lock."""

    def __init__(self, condition: Condition, banks: _SharedBanks):
        self._condition, self._banks = condition, banks

    def __getattr__(self, name):
        return getattr(self._condition, name)

    def open_tools(self, banks, participant):
        toolset = self._condition.open_tools(self._banks, participant)
        return None if toolset is None else _LockedTools(toolset, self._banks.tool_lock)


def _run_plan_concurrent(out, banks, conds, kinds, plan, memories, policy, summary, on_item, concurrency) -> None:
    """`run_plan` with `concurrency` items in flight: the same jobs in the same order, and
    records written in that order as soon as every earlier one is written."""
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    shared = _SharedBanks(banks)
    jobs: list[tuple[str, Condition, str, Any, str, bool]] = []  # pid, condition, kind, item, item_id, skip
    existing: dict[tuple[str, str], dict] = {}
    for pid in dict.fromkeys(p for p, _, _ in plan):
        for cond in conds:
            for kind in kinds:
                if (kind, cond.name) not in existing:
                    existing[(kind, cond.name)] = read_records(record_path(out, kind, cond.name))
                for p, k, item in plan:
                    if p != pid or k != kind:
                        continue
                    item_id = item.question_id if kind == "eam_qa" else item.task_id
                    skip = existing[(kind, cond.name)].get(item_id, {}).get("status") == "ok"
                    jobs.append((pid, cond, kind, item, item_id, skip))
    left = {}  # pid -> jobs not yet finished (its memories close at 0)
    for pid, *_rest, skip in jobs:
        left[pid] = left.get(pid, 0) + (not skip)
    files: dict[Path, Any] = {}
    results: dict[int, dict[str, Any] | None] = {}
    next_write = 0

    def write_ready() -> None:
        nonlocal next_write
        while next_write in results:
            pid, cond, kind, _, item_id, skip = jobs[next_write]
            rec = results.pop(next_write)
            next_write += 1
            if skip:
                summary.skipped += 1
                if on_item:
                    on_item({"condition": cond.name, "item_id": item_id, "status": "skipped"})
                continue
            path = record_path(out, kind, cond.name)
            if path not in files:
                path.parent.mkdir(parents=True, exist_ok=True)
                files[path] = path.open("a", encoding="utf-8")
            files[path].write(json.dumps(rec, ensure_ascii=False, default=str) + "\n")
            files[path].flush()
            summary.done += 1
            summary.failed += rec["status"] != "ok"
            summary.per_condition_seconds[cond.name] = summary.per_condition_seconds.get(cond.name, 0.0) + (
                rec.get("time", {}).get("total_s", 0.0))
            if on_item:
                on_item(rec)

    try:
        with ThreadPoolExecutor(max_workers=concurrency, thread_name_prefix="bench-item") as pool:
            pending: dict[Any, int] = {}
            i = 0
            try:
                while i < len(jobs) or pending:
                    while i < len(jobs) and len(pending) < 2 * concurrency:  # a bounded queue ahead of the pool
                        pid, cond, kind, item, _, skip = jobs[i]
                        if skip:
                            results[i] = None
                        else:
                            pending[pool.submit(run_item, policy, _LockedCondition(cond, shared), shared, kind, item,
                                                memories[pid], pid)] = i
                        i += 1
                    write_ready()
                    if not pending:
                        continue
                    done, _ = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in done:
                        j = pending.pop(fut)
                        results[j] = fut.result()  # run_item records failures; anything else is a bug
                        pid = jobs[j][0]
                        left[pid] -= 1
                        if left[pid] == 0:
                            shared.release(pid)
                    write_ready()
            except BaseException:  # Ctrl-C or a bug: items not started are dropped; written records stay
                for fut in pending:
                    fut.cancel()
                raise
    finally:
        for fh in files.values():
            fh.close()
        for pid in left:
            shared.release(pid)


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _write_manifest(out, bank, raw_bank, episodic_bank, conds, suite, tasks, backend, options, policy, kinds, limit,
                    workers=1, concurrency=1) -> None:
    path = out / "manifest.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    safe_options = {k: ("***" if "key" in k.lower() else v) for k, v in options.items()}
    digest = task_set_hash(suite)
    if old and (old.get("task_set_hash") != digest or old.get("backend") != backend):
        raise MemoraError(f"{out}: holds a run with another task set or backend "
                          f"({old.get('task_set_hash')}/{old.get('backend')}); use another --out")
    manifest = {
        **old,
        "format": RUN_FORMAT, "code_version": _code_version(), "prompt_version": PROMPT_VERSION,
        "backend": backend, "model": (getattr(getattr(policy, "backend", None), "model", None) or policy.name) if policy else backend,
        "workers": workers, "concurrency": concurrency,
        "options": safe_options, "seeds": {"offline_policy": "deterministic (no sampling)"},
        "temperature": None if not is_model_policy(backend) else options.get("temperature", DEFAULT_TEMPERATURE),
        "bank": str(bank), "raw_bank": str(raw_bank) if raw_bank else None,
        "episodic_bank": str(episodic_bank) if episodic_bank else None,
        "tasks": str(tasks) if tasks else "bundled calibration cohort", "task_set_hash": digest,
        "participants": sorted(suite.participants), "kinds": list(kinds), "limit": limit,
        "conditions": sorted(set(old.get("conditions", [])) | {c.name for c in conds}),
        "started_at": old.get("started_at") or _now(),
    }
    path.write_text(json.dumps(manifest, indent=2))


RESULT_COLUMNS = ("kind", "condition", "participant", "item_id", "status", "qa_type", "split", "task_type",
                  "correct_answer", "predicted", "is_correct", "n_tool_calls", "iterations", "forced")


def write_results_table(out: str | Path) -> Path:
    """results.parquet: one row per item (its latest record), scores flattened for planning."""
    out = Path(out)
    rows = []
    for kind, per_cond in load_run(out).items():
        for recs in per_cond.values():
            for r in recs:
                row = {c: r.get(c) for c in RESULT_COLUMNS}
                row["kind"] = r.get("kind", kind)
                for k, v in (r.get("time") or {}).items():
                    row[k] = v
                for k, v in (r.get("scores") or {}).items():
                    if k not in ("task_id", "metric_source"):
                        row[f"score_{k}"] = v
                rows.append(row)
    path = out / "results.parquet"
    pl.DataFrame(rows, infer_schema_length=None).write_parquet(path) if rows else None
    return path

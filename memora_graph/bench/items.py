"""Running the items of an evaluation: one item's record (`run_item`), a plan of items in this
process into a run folder's records files (`run_plan`), the answer policy that runs them
(`make_policy`). `run.py` deals the plan to this process, to worker processes or to Ray tasks
(`ray.py`); each runs it with `run_plan`, so a record is the same wherever it was made.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from memora_graph.agent.loop import run_agent
from memora_graph.agent.policies import is_model_policy
from memora_graph.bench.answers import extract_plan, parse_answer_letter, parse_confidence, parse_reader_features
from memora_graph.bench.conditions import BankSet, Condition
from memora_graph.bench.metrics import score_plan

KINDS = ("eam_qa", "replay", "generalize")
DEFAULT_TEMPERATURE = 0.6


@dataclass
class RunSummary:
    out: Path
    done: int = 0
    skipped: int = 0
    failed: int = 0
    seconds: float = 0.0
    items_seconds: float = 0.0  # running the items (after the run's setup: scoring memory, formation stats)
    per_condition_seconds: dict[str, float] = field(default_factory=dict)


# -- records files ----------------------------------------------------------------------------------


def record_path(out: Path, kind: str, condition: str) -> Path:
    return out / "records" / ("eam_qa" if kind == "eam_qa" else "planning") / f"{condition}.jsonl"


def read_records(path: Path) -> dict[str, dict]:
    """item id -> the last record written for it (a retried item replaces its failed record)."""
    out: dict[str, dict] = {}
    if not path.exists():
        return out
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue  # a line cut by a killed run; the item runs again
        out[rec["item_id"]] = rec
    return out


# -- one item ---------------------------------------------------------------------------------------


def structure_steps(steps: list[str], memory: dict[str, Any] | None) -> list[dict[str, Any]]:
    """(action, entity, location) per plan step; entity and location are drawn from the
    participant's memory (object names, places) when the condition has memory."""
    from memora_graph.bench.vocabulary import LOCATION_NOUNS, extract_action_verb

    names = sorted(memory["object_names"], key=len, reverse=True) if memory else []
    places = sorted(memory["places"], key=len, reverse=True) if memory else []
    out = []
    for s in steps:
        low = s.lower()
        entity = next((n for n in names if n.lower() in low), None)
        location = next((p for p in places if p and p.lower() in low), None)
        if location is None:
            location = next((p for p in sorted(LOCATION_NOUNS, key=len, reverse=True) if f" {p}" in f" {low}"), None)
        out.append({"text": s, "action": extract_action_verb(s), "entity": entity, "location": location,
                    "from_memory": bool(memory) and entity is not None})
    return out


def run_item(policy, condition: Condition, banks: BankSet, kind: str, item: Any, memory: dict | None,
              participant: str) -> dict[str, Any]:
    t0 = time.perf_counter()
    base: dict[str, Any] = {"condition": condition.name, "participant": participant, "kind": kind,
                            "status": "ok", "error": None}
    if kind == "eam_qa":
        view = item.answering_view()
        base.update(item_id=item.question_id, question_id=item.question_id, qa_type=item.qa_type,
                    is_unanswerable=item.is_unanswerable, correct_answer=item.correct_answer)
    else:
        view = {"task_id": item.task_id, "participant_id": item.participant_id, "task_query": item.task_query}
        base.update(item_id=item.task_id, task_id=item.task_id, split=kind, task_type=item.task_type,
                    task_query=item.task_query)
    try:
        toolset = condition.open_tools(banks, participant)
        res = run_agent(policy, toolset, "eam_qa" if kind == "eam_qa" else "planning", view, condition.prompt_family)
        base.update(final_text=res.final_text, iterations=res.iterations, forced=res.forced, retried=res.retried,
                    tool_calls=res.tool_calls, n_tool_calls=len(res.tool_calls),
                    time={"model_s": round(res.model_s, 4), "tools_s": round(res.tools_s, 4),
                          "other_s": round(res.other_s + 0.0, 4), "total_s": 0.0})
        if kind == "eam_qa":
            base["predicted"] = parse_answer_letter(res.final_text, view["choices"])
            base["is_correct"] = base["predicted"] == item.correct_answer
            base["confidence"] = parse_confidence(res.final_text)
            base["reader_features"] = parse_reader_features(res.final_text)
        else:
            steps = extract_plan(res.final_text)
            base["plan_text"] = "\n".join(f"{i}. {s}" for i, s in enumerate(steps, 1))
            base["generated_plan"] = steps
            base["structured_steps"] = structure_steps(steps, memory if condition.bank != "none" else None)
            base["scores"] = score_plan(steps, item.model_dump(), memory["routines"], memory["preferences"],
                                        memory["object_names"])
    except Exception as exc:  # recorded, never fatal
        base.update(status="failed", error=f"{type(exc).__name__}: {exc}")
        if kind == "eam_qa":
            base.update(predicted="", is_correct=False)
        else:
            base.update(generated_plan=[], plan_text="",
                        scores=score_plan([], item.model_dump(), memory["routines"], memory["preferences"],
                                          memory["object_names"]) if memory else {"empty": True})
    total = time.perf_counter() - t0
    t = base.setdefault("time", {"model_s": 0.0, "tools_s": 0.0, "other_s": 0.0})
    t["total_s"] = round(total, 4)
    t["other_s"] = round(max(0.0, total - t["model_s"] - t["tools_s"]), 4)
    return base


# -- a plan of items in this process ----------------------------------------------------------------


def make_policy(backend: str, options: dict[str, Any], out: Path):
    """The answer policy registered as `backend` (memora_graph/agent/policies.py); a model's calls
    go to OUT/model_calls.jsonl, at the evaluation's default temperature unless one is given."""
    from memora_graph.agent.policies import make_answer_policy

    opts = dict(options)
    if is_model_policy(backend):
        opts.setdefault("temperature", DEFAULT_TEMPERATURE)
    return make_answer_policy(backend, opts, Path(out) / "model_calls.jsonl")


def one_torch_thread():
    """Short MiniLM encodes are several times faster on one torch thread on small CPUs (they do
    not fight Kùzu and each other); scoped to the run."""
    from memora_graph.embed import torch_threads  # a broken import is an error, not a silent no-op

    return torch_threads(1)


def run_plan(out, banks, conds, kinds, plan, memories, policy, summary, on_item) -> None:
    for pid in dict.fromkeys(p for p, _, _ in plan):
        memory = memories[pid]
        for cond in conds:
            t_cond = time.perf_counter()
            for kind in kinds:
                path = record_path(out, kind, cond.name)
                existing = read_records(path)
                path.parent.mkdir(parents=True, exist_ok=True)
                with path.open("a", encoding="utf-8") as fh:
                    for p, k, item in plan:
                        if p != pid or k != kind:
                            continue
                        item_id = item.question_id if kind == "eam_qa" else item.task_id
                        if existing.get(item_id, {}).get("status") == "ok":
                            summary.skipped += 1
                            if on_item:
                                on_item({"condition": cond.name, "item_id": item_id, "status": "skipped"})
                            continue
                        rec = run_item(policy, cond, banks, kind, item, memory, pid)
                        fh.write(json.dumps(rec, ensure_ascii=False, default=str) + "\n")
                        fh.flush()
                        summary.done += 1
                        summary.failed += rec["status"] != "ok"
                        if on_item:
                            on_item(rec)
            summary.per_condition_seconds[cond.name] = summary.per_condition_seconds.get(cond.name, 0.0) + (
                time.perf_counter() - t_cond)

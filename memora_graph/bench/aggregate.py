"""Aggregation of per-item records into the reported numbers: EAM-QA accuracy, E-selection rate and
per-type accuracy, the three evaluation views (pooled and macro over participants), and the
planning panel per condition with RGP. Pure functions over records."""

from __future__ import annotations

from collections import defaultdict
from statistics import mean
from typing import Any, Iterable

from memora_graph.bench.answers import CONTENT_LETTERS
from memora_graph.bench.metrics import AXES, RGP_AXES

def _pred(record: dict) -> str:
    return (record.get("predicted", record.get("predicted_answer")) or "").strip().upper()


def eam_scores(records: Iterable[dict]) -> dict[str, Any]:
    """Accuracy, E-selection rate, and both per type.

    Each record: {question_id, qa_type, correct_answer, predicted} ("predicted_answer" is
    accepted too; a question that failed is scored with predicted "").
    """
    records = list(records)
    n = len(records)
    correct = sum(_pred(r) == r["correct_answer"] for r in records)
    chose_e = sum(_pred(r) == "E" for r in records)
    by_type: dict[str, list[dict]] = defaultdict(list)
    for r in records:
        by_type[r.get("qa_type", "")].append(r)
    return {
        "n": n,
        "correct": correct,
        "accuracy": correct / n if n else None,
        "e_rate": chose_e / n if n else None,
        "per_type_n": {t: len(rs) for t, rs in sorted(by_type.items())},
        "per_type_accuracy": {t: sum(_pred(r) == r["correct_answer"] for r in rs) / len(rs) for t, rs in sorted(by_type.items())},
        "per_type_e_rate": {t: sum(_pred(r) == "E" for r in rs) / len(rs) for t, rs in sorted(by_type.items())},
        "failed_questions": sorted(r["question_id"] for r in records if _pred(r) == ""),
    }


VIEWS = ("full", "memora_committed", "parametric_missed_memora_committed")


def eam_views(
    results: dict[str, dict[str, list[dict]]],
    memora: str = "memora_full",
    parametric: str = "no_memory",
    baselines: list[str] | None = None,
) -> dict[str, Any]:
    """The paper's three EAM-QA views, pooled (item-weighted) and macro-averaged over participants.

    `results[condition][participant]` is that condition's list of records (see eam_scores).
    Within each participant every condition is scored on the same ids: the ids all conditions
    answered (full); of those, the ids where `memora` chose A-D (MEMORA-committed); of those,
    the ids where `parametric` was wrong (parametric-missed + MEMORA-committed). Baselines for
    delta_pp default to every condition except memora, memora_episodic and parametric.
    Also reports the commit rate P(memora A-D | parametric wrong), pooled.
    """
    if memora not in results:
        raise ValueError(f"no results for the MEMORA condition {memora!r}; have {sorted(results)}")
    conditions = sorted(results)
    if baselines is None:
        baselines = [c for c in conditions if c not in (memora, "memora_episodic", parametric)]
    participants = sorted(set().union(*(results[c].keys() for c in conditions)))
    index = {c: {p: {r["question_id"]: r for r in results[c].get(p, [])} for p in participants} for c in conditions}
    eligible: dict[str, dict[str, set[str]]] = {v: {} for v in VIEWS}
    missed_total = committed_missed = 0
    for p in participants:
        common = set.intersection(*(set(index[c][p]) for c in conditions))
        committed = {q for q in common if _pred(index[memora][p][q]) in CONTENT_LETTERS}
        eligible["full"][p] = common
        eligible["memora_committed"][p] = committed
        if parametric in results:
            missed = {q for q in common if _pred(index[parametric][p][q]) != index[parametric][p][q]["correct_answer"]}
            eligible["parametric_missed_memora_committed"][p] = committed & missed
            missed_total += len(missed)
            committed_missed += len(committed & missed)
    out: dict[str, Any] = {}
    for view in VIEWS:
        if view == "parametric_missed_memora_committed" and parametric not in results:
            continue
        per_condition = {}
        for c in conditions:
            per_p = {}
            for p in participants:
                ids = eligible[view][p]
                right = sum(_pred(index[c][p][q]) == index[c][p][q]["correct_answer"] for q in ids)
                per_p[p] = {"correct": right, "total": len(ids), "accuracy": right / len(ids) if ids else None}
            total = sum(v["total"] for v in per_p.values())
            right = sum(v["correct"] for v in per_p.values())
            accs = [v["accuracy"] for v in per_p.values() if v["accuracy"] is not None]
            per_condition[c] = {
                "n": total, "pooled": right / total if total else None,
                "macro": mean(accs) if accs else None, "per_participant": per_p,
            }
        scored = [(per_condition[b]["pooled"], b) for b in baselines if per_condition.get(b, {}).get("pooled") is not None]
        best = max(scored) if scored else (None, None)
        mem = per_condition[memora]["pooled"]
        out[view] = {
            "conditions": per_condition, "best_baseline": best[1],
            "delta_pp": 100 * (mem - best[0]) if mem is not None and best[0] is not None else None,
        }
    out["commit_rate"] = committed_missed / missed_total if missed_total else None
    return out


def planning_panel(task_scores: list[dict]) -> dict[str, Any]:
    """Condition-level means of every axis over the tasks where it is defined (empty plans are
    excluded and counted), and RGP = mean of the defined OrderExec, KeyObj and PrefAdh means."""
    scored = [s for s in task_scores if not s.get("empty")]
    out: dict[str, Any] = {"n_plans_scored": len(scored), "n_empty_plans": len(task_scores) - len(scored)}
    for axis in AXES:
        values = [s[axis] for s in scored if s.get(axis) is not None]
        out[axis] = round(mean(values), 4) if values else None
        out[f"n_{axis}"] = len(values)
    defined = [out[a] for a in RGP_AXES if out[a] is not None]
    out["rgp"] = round(mean(defined), 4) if defined else None
    return out


def rgp(order_exec_mean: float | None, key_obj_mean: float | None, pref_adh_mean: float | None) -> float | None:
    """RGP from condition-level means; undefined components are skipped."""
    defined = [v for v in (order_exec_mean, key_obj_mean, pref_adh_mean) if v is not None]
    return round(mean(defined), 4) if defined else None

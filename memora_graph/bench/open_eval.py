"""The open-question evaluation: answer generated open questions from a bank, score by type.

    memora bench open banks/epic --participants P01,P02,P03

Per item: the reader's typed answer (`agent.query`), right or wrong by the item's type
(`generate_open.score_item`), its confidence. The summary: accuracy per kind and per wording
split (dev / heldout), the "not in memory" reason, the expected calibration error of the
confidence with its reliability table, and accuracy when answering only the 50% / 80% most
confident questions (selective answering).
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable

from memora_graph.bench.generate_open import OpenItem, score_item
from memora_graph.bench.generate_scoped import CELLS


def load_items(folder: Path, participants: list[str]) -> dict[str, list[OpenItem]]:
    out = {}
    for pid in participants:
        path = Path(folder) / f"{pid.lower()}.json"
        if not path.exists():
            from memora_graph.errors import DataError

            raise DataError(f"{path}: no open questions for {pid} (generate them with `memora bench generate --kind open`)")
        out[pid] = [OpenItem.model_validate(x) for x in json.loads(path.read_text())["questions"]]
    return out


def evaluate_open(bank: str | Path, items: dict[str, list[OpenItem]],
                  on_item: Callable[[dict], None] | None = None) -> list[dict[str, Any]]:
    """Answer and score every item; one record per item."""
    from memora_graph.agent.query.answer import answer_open
    from memora_graph.perceive.lexicon import Lexicon
    from memora_graph.retrieve.view import MemoryView

    lex = Lexicon.load()
    records = []
    for pid, its in items.items():
        with MemoryView.open(Path(bank), pid) as view:
            for it in its:
                a = answer_open(view, pid, it.question, lex)
                s = score_item(it, a)
                op, scope = CELLS.get(it.kind, (it.kind, "all"))
                rec = {"question_id": it.question_id, "participant": pid, "kind": it.kind, "split": it.split,
                       "template": it.template, "question": it.question, "gold": it.gold, "asked": a.asked,
                       "cell": f"{op} x {scope}", "pair": it.evidence.get("pair"), "value": answer_value(a),
                       "answer_kind": a.kind, "answer": a.answer, "reason": a.reason, **s,
                       "confidence": a.confidence, "features": a.features, "evidence": a.evidence[:5]}
                records.append(rec)
                if on_item:
                    on_item(rec)
    return records


def answer_value(a) -> str:
    """The typed value an answer gives (what the counterfactual check compares)."""
    if not a.in_memory:
        return f"nim:{a.reason}"
    if a.place is not None:
        return f"place:{a.place.place}"
    if a.count is not None:
        return f"count:{a.count}"
    if a.yes is not None:
        return f"yes:{a.yes}"
    if a.moment is not None and not a.actions:
        return f"video:{a.moment.video}"
    if a.actions:
        return f"action:{a.actions[0].verb}/{a.actions[0].noun}"
    return f"text:{a.answer}"


def counterfactual(records: list[dict]) -> dict:
    """Questions that differ only in their scope, whose gold differs: did the answer change?"""
    pairs: dict[str, list[dict]] = defaultdict(list)
    for r in records:
        if r.get("pair"):
            pairs[r["pair"]].append(r)
    checked = changed = 0
    misses = []
    for key, rs in pairs.items():
        for i in range(len(rs)):
            for j in range(i + 1, len(rs)):
                if rs[i]["gold"] == rs[j]["gold"]:
                    continue
                checked += 1
                if rs[i]["value"] != rs[j]["value"]:
                    changed += 1
                else:
                    misses.append(key)
    return {"pairs": checked, "changed": changed, "rate": round(changed / checked, 4) if checked else None,
            "unchanged": misses[:20]}


def _acc(recs: list[dict]) -> dict:
    n = len(recs)
    return {"n": n, "correct": sum(r["correct"] for r in recs), "accuracy": round(sum(r["correct"] for r in recs) / n, 4)
            if n else None}


def selective(records: list[dict], coverage: float) -> float | None:
    """Accuracy on the `coverage` share of questions with the highest confidence."""
    ranked = sorted(records, key=lambda r: -r["confidence"])
    k = max(1, round(coverage * len(ranked))) if ranked else 0
    return round(sum(r["correct"] for r in ranked[:k]) / k, 4) if k else None


def summarize(records: list[dict]) -> dict[str, Any]:
    from memora_graph.agent.open_calibration import ece

    by_kind, by_split, by_cell = defaultdict(list), defaultdict(list), defaultdict(list)
    for r in records:
        by_kind[r["kind"]].append(r)
        by_split[r["split"]].append(r)
        by_cell[r.get("cell", r["kind"])].append(r)
    nim = [r for r in records if r["reason_ok"] is not None]
    err, table = ece([r["confidence"] for r in records], [r["correct"] for r in records])
    return {"overall": _acc(records), "per_kind": {k: _acc(v) for k, v in sorted(by_kind.items())},
            "per_split": {k: _acc(v) for k, v in sorted(by_split.items())},
            "per_cell": {k: _acc(v) for k, v in sorted(by_cell.items())},
            "counterfactual": counterfactual(records),
            "nim_reason_accuracy": round(sum(r["reason_ok"] for r in nim) / len(nim), 4) if nim else None,
            "ece": err, "reliability": table,
            "selective": {"100%": _acc(records)["accuracy"], "80%": selective(records, 0.8),
                          "50%": selective(records, 0.5)}}


def fit_calibration(records: list[dict], path: Path, participants: list[str], command: str) -> dict:
    """Fit the answer probability on these records and write it to `path`."""
    from memora_graph.agent.open_calibration import ece, fit, probability, write

    weights = fit([(r["answer_kind"], r["features"]) for r in records], [r["correct"] for r in records])
    probs = [probability(r["answer_kind"], r["features"], weights) for r in records]
    err, _ = ece(probs, [r["correct"] for r in records])
    write(path, weights, participants, len(records), command, {"ece_on_fit": err})
    return {"weights": weights, "ece_on_fit": err}

"""Two evaluation runs side by side, record by record (`memora bench compare`).

A refactor, a faster encoder or another executor should leave the records alone: predictions,
plans, tool calls and their arguments. This reads two run directories (`memora bench run --out`)
and counts, per task kind and condition, the records that differ once timings are set aside, the
answers and plans that changed, and which fields differ; plus the first differing items.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from memora_graph.bench.aggregate import eam_scores
from memora_graph.bench.run import load_run
from memora_graph.errors import MemoraError

# What varies between two runs of the same code: wall and CPU times, when it ran.
TIMING_KEYS = frozenset({"time", "seconds", "started_at", "finished_at"})
TIMING_SUFFIXES = ("_s", "_ms", "_seconds")
# What a reader of the comparison cares about first: the answer, or the plan.
ANSWER_FIELDS = {"eam_qa": ("predicted",), "planning": ("generated_plan",)}


def without_timings(value: Any) -> Any:
    """`value` with every timing field removed, at any depth (tool calls carry their own)."""
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items()
                if k not in TIMING_KEYS and not k.endswith(TIMING_SUFFIXES)}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


@dataclass
class Difference:
    kind: str
    condition: str
    item_id: str
    fields: list[str]


@dataclass
class RunComparison:
    rows: list[dict] = field(default_factory=list)  # one per (kind, condition)
    differences: list[Difference] = field(default_factory=list)

    @property
    def identical(self) -> bool:
        return all(r["only_a"] == 0 and r["only_b"] == 0 and r["differ"] == 0 for r in self.rows)


def _accuracy(records: list[dict]) -> float | None:
    """EAM-QA accuracy in percent as the report computes it (a failed item counts as wrong)."""
    acc = eam_scores(records)["accuracy"]
    return None if acc is None else round(100 * acc, 1)


def compare_runs(a: str | Path, b: str | Path) -> RunComparison:
    """Compare run `a` with run `b` (see the module docstring). Raises MemoraError naming the
    directory when either is not a run."""
    runs = []
    for path in (Path(a), Path(b)):
        if not (path / "records").is_dir():
            raise MemoraError(f"{path}: not a run directory (no records/ folder; `memora bench run --out DIR` "
                              "writes one)")
        runs.append(load_run(path))
    out = RunComparison()
    for kind in ("eam_qa", "planning"):
        for cond in sorted(set(runs[0][kind]) | set(runs[1][kind])):
            ra = {r["item_id"]: r for r in runs[0][kind].get(cond, [])}
            rb = {r["item_id"]: r for r in runs[1][kind].get(cond, [])}
            both = [i for i in ra if i in rb]
            fields: Counter = Counter()
            differ = changed = 0
            for item in both:
                x, y = without_timings(ra[item]), without_timings(rb[item])
                if x == y:
                    continue
                differ += 1
                names = sorted(k for k in set(x) | set(y) if x.get(k) != y.get(k))
                fields.update(names)
                changed += any(x.get(f) != y.get(f) for f in ANSWER_FIELDS[kind])
                out.differences.append(Difference(kind, cond, item, names))
            row = {"kind": kind, "condition": cond, "records_a": len(ra), "records_b": len(rb), "only_a": len(ra) - len(both),
                   "only_b": len(rb) - len(both), "differ": differ, "answers_changed": changed,
                   "fields_differing": ", ".join(f"{k} ({n})" for k, n in fields.most_common()) or "-"}
            # EAM-QA accuracy of each run, so a changed answer's cost shows (plans: None)
            row["accuracy_a"] = _accuracy(list(ra.values())) if kind == "eam_qa" else None
            row["accuracy_b"] = _accuracy(list(rb.values())) if kind == "eam_qa" else None
            out.rows.append(row)
    if not out.rows:
        raise MemoraError(f"{a} and {b}: no records in either run")
    return out

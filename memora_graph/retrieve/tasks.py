"""A participant's tasks (the Task rows, consolidate/tasks.py) as a planner reads them: every row, in
video and time order, indexed by the object kinds each names, with every step's verb and kinds as
columns, so that matching a goal against every task is a few columnar operations.

A task names a kind when the kind is one of its objects, or a step acts on it, with it, or puts
something at it (`step_kinds`). A plan for a goal (agent/task_match.py) only considers the tasks that
name the goal's objects (`having`), counts their steps on those objects (`step_counts`), and parses
the steps of the one it picks (`task`). At 1,000 h a participant has 39,787 tasks (about 800,000
steps): reading them as dicts and parsing every step list took 2.5 s, and matching one goal against
all of them in Python 300-860 ms.

The index is one columnar read of what matching needs (`queries/_task_index.cypher`; sorted here, as
Kùzu's sort held another copy of every step list: 550 MB more at the peak at 1,000 h, 410 unsorted),
its step lists decoded by polars a slice at a time and then dropped; the task a plan picks is read whole by its id
(`_task_row`). A `MemoryView` keeps its index until a consolidation replaces the tasks
(`reload_inferred`)."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from typing import Any

import polars as pl

from memora_graph.errors import BankError

_STEP = pl.List(pl.Struct({"verb": pl.Utf8, "noun": pl.Utf8, "instrument": pl.Utf8, "place": pl.Utf8}))
_KIND_COLUMNS = ("noun", "instrument", "place")
DECODE_CHUNK = 256  # tasks whose steps are decoded at once (at 1,000 h: 256 held 130 MB more, 2,048 250 MB, 8,192 700 MB)


def step_kinds(step: dict[str, Any]) -> set[str]:
    """The object kinds a task step names: what it acts on, with, and where it puts it (a place's
    words joined as a kind's are: "drying rack" -> "drying_rack")."""
    place = (step.get("place") or "").replace(" ", "_")
    return {k for k in (step.get("noun"), step.get("instrument"), place) if k}


class TaskIndex:
    """The Task rows of one participant (see the module). A task is known by its position in the
    rows' order (video, start, id)."""

    def __init__(self, rows: pl.DataFrame, parsed: dict[int, dict[str, Any]] | None = None, source: str = "",
                 row_of: Callable[[str], dict[str, Any] | None] | None = None):
        """`rows`: id, goal, family, objects and steps (JSON) of each task; `row_of(id)`: a task's
        whole row (`task`), or None for an index that keeps the rows it was made of (`parsed`)."""
        self._parsed: dict[int, dict[str, Any]] = dict(parsed or {})
        self._row_of = row_of
        rows = rows.with_row_index("i")
        parts, n_steps = [], []  # a slice of tasks at a time: decoding all 800,000 steps at once held 1.7 GB
        for chunk in rows.select("i", "id", "steps").iter_slices(DECODE_CHUNK):
            try:
                decoded = chunk.select("i", pl.col("steps").str.json_decode(_STEP).alias("s"))
            except pl.exceptions.PolarsError as exc:
                bad = next((r["id"] for r in chunk.iter_rows(named=True) if not _json_ok(r["steps"])), "?")
                raise BankError(f"{source or 'the bank'}: task {bad} has steps that are not a JSON list of steps "
                                f"({exc}); re-run `memora consolidate` on the bank to write its tasks again") from exc
            n_steps += decoded["s"].list.len().fill_null(0).to_list()
            parts.append(decoded.explode("s").unnest("s")
                         .filter(pl.any_horizontal(pl.col(c).is_not_null() for c in ("verb", *_KIND_COLUMNS)))
                         .with_columns(pl.col(c).fill_null("") for c in ("verb", *_KIND_COLUMNS))
                         .with_columns(pl.col("place").str.replace_all(" ", "_", literal=True))
                         .with_columns(pl.col(c).cast(pl.Categorical) for c in ("verb", *_KIND_COLUMNS)))
        self._rows = rows.select("i", "id", "goal", "family", "objects")
        self._n_steps = n_steps
        self._steps = pl.concat(parts) if parts else pl.DataFrame(
            schema={"i": pl.UInt32, **{c: pl.Categorical for c in ("verb", *_KIND_COLUMNS)}})
        objects = self._rows.select("i", pl.col("objects").alias("kind")).explode("kind") \
            .with_columns(pl.col("kind").cast(pl.Categorical))
        self._kinds = pl.concat([*(self._steps.select("i", pl.col(c).alias("kind")) for c in _KIND_COLUMNS), objects]) \
            .filter(pl.col("kind").is_not_null() & (pl.col("kind") != "")).unique()
        self._kind_names = frozenset(self._kinds["kind"].unique().cast(pl.Utf8).to_list())
        self._verbs = frozenset(self._steps["verb"].unique().cast(pl.Utf8).to_list())

    @classmethod
    def empty(cls) -> TaskIndex:
        return cls.of([])

    @classmethod
    def of(cls, tasks: Iterable[dict[str, Any]]) -> TaskIndex:
        """An index over task rows already read, their steps parsed (lists of step dicts)."""
        tasks = list(tasks)
        rows = pl.DataFrame({"id": [str(t.get("id", n)) for n, t in enumerate(tasks)],
                             "goal": [t.get("goal") or "" for t in tasks],
                             "family": [t.get("family") or "" for t in tasks],
                             "objects": [list(t.get("objects") or []) for t in tasks],
                             "steps": [json.dumps(t.get("steps") or []) for t in tasks]},
                            schema={"id": pl.Utf8, "goal": pl.Utf8, "family": pl.Utf8, "objects": pl.List(pl.Utf8),
                                    "steps": pl.Utf8})
        return cls(rows, dict(enumerate(tasks)))

    @classmethod
    def read(cls, store, participant: str) -> TaskIndex:
        """Every Task row of `participant` in `store` (an open database); empty for one built
        before tasks existed."""
        if "Task" not in store.tables():
            return cls.empty()

        def row_of(task_id: str) -> dict[str, Any] | None:
            got = store.fetch("_task_row", participant=participant, id=task_id)
            return dict(got[0]) if got else None

        rows = store.fetch_frame("_task_index", participant=participant) \
            .sort("video", "t_start", "id", nulls_last=True)  # as `tasks` orders them
        return cls(rows, source=str(getattr(store, "path", "")), row_of=row_of)

    def __len__(self) -> int:
        return self._rows.height

    def kinds(self) -> frozenset[str]:
        """Every object kind some task names."""
        return self._kind_names

    def verbs(self) -> frozenset[str]:
        """Every verb some task's step says."""
        return self._verbs

    def having(self, kinds: Iterable[str]) -> set[int]:
        """The positions of the tasks that name any of `kinds`."""
        wanted = pl.Series(sorted(set(kinds) & self._kind_names), dtype=pl.Utf8)
        if wanted.is_empty():
            return set()
        return set(self._kinds.filter(pl.col("kind").cast(pl.Utf8).is_in(wanted.implode()))["i"].to_list())

    def step_counts(self, tasks: set[int], on: set[str], made: set[str], verbs: set[str] | None
                    ) -> list[tuple[int, str, str, int, int, bool, int]]:
        """For each of `tasks`, in order: (position, goal, family, its steps naming a kind in `on`, of
        those the steps naming one in `made`, whether one of those says a verb in `verbs` (None:
        True), all its steps)."""
        if not tasks:
            return []
        chosen = pl.Series("i", sorted(tasks), dtype=self._steps.schema["i"])
        on_, made_ = pl.Series(sorted(on), dtype=pl.Utf8), pl.Series(sorted(made), dtype=pl.Utf8)
        hits = self._steps.filter(pl.col("i").is_in(chosen.implode())).filter(
            pl.any_horizontal(pl.col(c).cast(pl.Utf8).is_in(on_.implode()) for c in _KIND_COLUMNS)
        ).group_by("i").agg(
            pl.len().alias("on"),
            pl.any_horizontal(pl.col(c).cast(pl.Utf8).is_in(made_.implode()) for c in _KIND_COLUMNS).sum().alias("made"),
            (pl.col("verb").cast(pl.Utf8).is_in(pl.Series(sorted(verbs), dtype=pl.Utf8).implode()).any() if verbs is not None
             else pl.lit(True)).alias("verb"),
        )
        got = {r[0]: r[1:] for r in hits.iter_rows()}
        goal, family = self._rows["goal"], self._rows["family"]
        return [(i, goal[i], family[i], *got.get(i, (0, 0, verbs is None)), self._n_steps[i]) for i in sorted(tasks)]

    def task(self, i: int) -> dict[str, Any]:
        """The task at position `i`, its steps parsed (a list of step dicts)."""
        got = self._parsed.get(i)
        if got is None:
            task_id = self._rows["id"][i]
            got = self._row_of(task_id) if self._row_of is not None else None
            if got is None:  # consolidated again since the index was read: the view reads them anew
                raise BankError(f"task {task_id} is no longer in memory; the tasks were written again since they "
                                "were read")
            got["steps"] = json.loads(got.get("steps") or "[]")
            self._parsed[i] = got
        return got

    def task_kinds(self, i: int) -> set[str]:
        """Every kind the task at `i` names."""
        t = self.task(i)
        return set(t.get("objects") or []).union(*(step_kinds(s) for s in t["steps"]))

    def __iter__(self):
        return (self.task(i) for i in range(len(self)))


def _json_ok(text: str | None) -> bool:
    try:
        return isinstance(json.loads(text or "[]"), list)
    except ValueError:
        return False

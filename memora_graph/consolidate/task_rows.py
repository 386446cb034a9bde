"""The tasks as Task rows (schema/005_tasks.cypher), and their bulk load.

A batch run's rows are made when the writer reads them (`TaskRows`) and copied a chunk of tasks
at a time (`copy_task_rows`), in the run's one transaction: the rows of every task (each with its
steps as JSON) are not all held at once beside Kùzu's copy of them. Figures: docs/build-memory.md.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator

from memora_graph import schema
from memora_graph.store import Store

CHUNK_TASKS = 2_000  # tasks per COPY
STAGES = ("setup", "main", "finish", "cleanup")


def task_row(participant: str, t, segment_ids) -> dict | None:
    """A task (`Task` or `CompactTask`) as a Task row citing only segments that exist; None if
    none of its segments does."""
    segs = [x for x in t.segments if x in segment_ids]
    if not segs:
        return None
    return {"id": t.id, "participant": participant, "video": t.video, "goal": t.goal, "family": t.family,
            "main_object": t.main_object, "t_start": float(t.t_start), "t_end": float(t.t_end),
            "objects": t.objects, "tools": t.tools, "places": t.places, "segments": segs,
            "stages": json.dumps({st: [s.text for s in t.stage(st)] for st in STAGES}),
            "steps": json.dumps([{**s.action.model_dump(), "stage": s.stage, "t": s.t, "segment": s.segment}
                                 for s in t.steps])}


class TaskRows:
    """The Task rows of `tasks` (`task_row`: a task citing no segment that exists has none), made
    when iterated: a run's rows are read once, by the writer, a chunk at a time."""

    def __init__(self, participant: str, tasks: list, segment_ids):
        self.participant, self.tasks, self.segment_ids = participant, tasks, segment_ids
        self._n = sum(1 for t in tasks if any(x in segment_ids for x in t.segments))

    def __len__(self) -> int:
        return self._n

    def __iter__(self) -> Iterator[dict]:
        for t in self.tasks:
            row = task_row(self.participant, t, self.segment_ids)
            if row is not None:
                yield row


def _chunks(rows: Iterable[dict], n: int) -> Iterator[list[dict]]:
    chunk: list[dict] = []
    for r in rows:
        chunk.append(r)
        if len(chunk) == n:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


def copy_task_rows(store: Store, rows: Iterable[dict], chunk: int | None = None) -> None:
    """COPY Task rows into the open store (in its transaction), `chunk` (CHUNK_TASKS) rows per frame."""
    for part in _chunks(rows, chunk or CHUNK_TASKS):
        store.copy("Task", schema.frame("Task", part))

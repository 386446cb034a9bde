"""Helpers the detectors share: readable words for steps and objects, and grouping of tasks."""

from __future__ import annotations

from collections import Counter, defaultdict

from memora_graph.consolidate import vocab
from memora_graph.consolidate.memory import display
from memora_graph.consolidate.task_records import Task

MIN_TASKS = 2  # a pattern needs at least this many tasks (occurrences) behind it
MAX_PER_FAMILY = 40  # records kept per family and participant (the best supported first)


def obj(kind: str) -> str:
    return display(kind.split(":")[0] if ":" not in kind else " ".join(reversed(kind.split(":"))))


def verb3(verb: str) -> str:
    return vocab.third_person(verb)


def recurring(tasks: list[Task]) -> dict[str, list[Task]]:
    """goal -> its tasks, for goals done at least MIN_TASKS times."""
    by: dict[str, list[Task]] = defaultdict(list)
    for t in tasks:
        by[t.goal].append(t)
    return {g: ts for g, ts in by.items() if len(ts) >= MIN_TASKS}


def with_object(tasks: list[Task]) -> Counter:
    """object kind -> the tasks handling it (`noun in t.objects`), counted once for every record."""
    return Counter(k for t in tasks for k in set(t.objects))


def videos_of(tasks: list[Task]) -> dict[str, int]:
    out: dict[str, int] = {}
    for t in tasks:
        out[t.video] = out.get(t.video, 0) + 1
    return dict(sorted(out.items()))


def top(records: list, n: int = MAX_PER_FAMILY) -> list:
    return sorted(records, key=lambda r: (-r.count, -r.confidence, r.key))[:n]

"""Staging places: an object put down at a place and picked up again within the same task, "the
counter as a landing spot between stages".

Rule: within a task, a releasing step (put, insert, ...) of an object at a place, followed later
in the task by a taking step (take, lift, ...) of the same object kind. Counted per (object, place)
over tasks, and per place over every object staged there. Kept at `MIN_TASKS` tasks or more.
"""

from __future__ import annotations

from collections import defaultdict

from memora_graph.consolidate import vocab
from memora_graph.consolidate.patterns._common import MIN_TASKS, obj, top, videos_of, with_object
from memora_graph.consolidate.records import StepAction
from memora_graph.consolidate.task_records import Task, TaskPattern


def _stagings(t: Task):
    """(object, place, put segment, taken again segment) for each staging in the task."""
    out = []
    open_: dict[str, tuple[str, str]] = {}
    for s in t.steps:
        a = s.action
        if a.verb in vocab.RELEASING and a.noun and a.place:
            open_[a.noun] = (a.place, s.segment)
        elif a.verb in vocab.TAKING and a.noun in open_:
            place, seg = open_.pop(a.noun)
            out.append((a.noun, place, seg, s.segment))
    return out


def detect(tasks: list[Task]) -> list[TaskPattern]:
    by_obj: dict[tuple[str, str], list[tuple[Task, str]]] = defaultdict(list)
    by_place: dict[str, list[tuple[Task, str, str]]] = defaultdict(list)
    for t in tasks:
        for noun, place, seg, _ in _stagings(t):
            by_obj[(noun, place)].append((t, seg))
            by_place[place].append((t, noun, seg))
    out = []
    with_obj = with_object(tasks)
    for (noun, place), occ in by_obj.items():
        n = len({t.id for t, _ in occ})
        if n < MIN_TASKS:
            continue
        handled = with_obj[noun]
        out.append(TaskPattern(
            family="staging", key=(noun, place),
            statement=f"Puts the {obj(noun)} down on the {place} and picks it up again later in the same task "
                      f"(stages it there in {n} of {handled} tasks with it)",
            objects=[noun], actions=[StepAction(verb="put", noun=noun, place=place), StepAction(verb="take", noun=noun, place=place)],
            count=n, total=max(n, handled), evidence=[s for _, s in occ][:20], tasks=sorted({t.id for t, _ in occ}),
            videos=videos_of([o[0] for o in occ]), detail={"place": place}))
    for place, occ in by_place.items():
        n = len({t.id for t, _, _ in occ})
        kinds = list(dict.fromkeys(k for _, k, _ in occ))
        if n < MIN_TASKS or len(kinds) < 2:
            continue
        out.append(TaskPattern(
            family="staging", key=("*", place),
            statement=f"Uses the {place} as a staging spot between steps: puts things down there and picks them up "
                      f"again ({', '.join(obj(k) for k in kinds[:5])}; {n} of {len(tasks)} tasks)",
            objects=kinds[:8], actions=[StepAction(verb="put", noun=k, place=place) for k in kinds[:4]],
            count=n, total=max(n, len(tasks)), evidence=[s for _, _, s in occ][:20],
            tasks=sorted({t.id for t, _, _ in occ}), videos=videos_of([t for t, _, _ in occ]), detail={"place": place}))
    return top(out)


"""Closing what was opened: "closes the cupboard after taking what it needs (32 of 34 times)", or
"leaves the bag open (6 of 7 times)".

Rule: within each task, every time an object is opened (verb class open), whether the same object
kind is closed later in the same task, and how soon: within `PROMPT` steps of the opening is
promptly. An object opened in at least `MIN_TASKS` tasks gets one record: the person closes it
when it was closed after at least `MIN_SHARE` of its openings, else leaves it open. The openings
that went the other way are its exceptions. Its detail says how many closes were prompt. When
at least two kinds of storage (cupboard, drawer, fridge: `vocab.STORAGE_KINDS`) were opened, one
more record pools them: how the person leaves their storage ("closes storage again after opening
it: cupboard, drawer, fridge").
"""

from __future__ import annotations

from collections import defaultdict

from memora_graph.consolidate import vocab
from memora_graph.consolidate.patterns._common import MIN_TASKS, obj, top, videos_of
from memora_graph.consolidate.records import StepAction
from memora_graph.consolidate.task_records import Task, TaskPattern

MIN_SHARE = 0.5  # of an object's openings closed again in the task: it is closed after use
PROMPT = 4  # steps from the opening to the close: closed promptly (take what is needed, close)


def detect(tasks: list[Task]) -> list[TaskPattern]:
    opened: dict[str, list[tuple[Task, str, int | None]]] = defaultdict(list)  # kind -> (task, segment, steps to close)
    for t in tasks:
        steps = t.steps
        for i, s in enumerate(steps):
            if s.action.verb != "open" or not s.action.noun:
                continue
            noun = s.action.noun
            j = next((j for j in range(i + 1, len(steps)) if steps[j].action.noun == noun
                      and steps[j].action.verb in ("close", "open")), None)
            closes = j is not None and steps[j].action.verb == "close"  # opened again first: left open between
            opened[noun].append((t, s.segment, j - i if closes else None))
    out = [r for noun, occ in opened.items() if (r := _record([noun], occ)) is not None]
    storage = sorted((k for k in opened if k in vocab.STORAGE_KINDS), key=lambda k: -len(opened[k]))
    if len(storage) >= 2:
        out.append(_record(storage, [o for k in storage for o in opened[k]]))
    return top([r for r in out if r is not None])


def _record(nouns: list[str], occ: list[tuple[Task, str, int | None]]) -> TaskPattern | None:
    ts = {t.id: t for t, _, _ in occ}
    if len(ts) < MIN_TASKS:
        return None
    closed = [(t, seg, d) for t, seg, d in occ if d is not None]
    left = [(t, seg, d) for t, seg, d in occ if d is None]
    m, n = len(occ), len(closed)
    prompt = sum(1 for _, _, d in closed if d <= PROMPT)
    pooled = len(nouns) > 1
    o = "storage" if pooled else f"the {obj(nouns[0])}"
    which = f": {', '.join(obj(k) for k in nouns)}" if pooled else ""
    if n / m >= MIN_SHARE:
        way, held, other = "closes", closed, left
        statement = f"Closes {o} again after opening it{which} ({n} of {m} times; promptly, within {PROMPT} steps, {prompt} of them)"
    else:
        way, held, other = "leaves_open", left, closed
        statement = f"Leaves {o} open after opening it{which} ({m - n} of {m} times)"
    return TaskPattern(
        family="closure", key=("storage" if pooled else nouns[0], way), statement=statement, objects=list(nouns),
        actions=[StepAction(verb="open", noun=nouns[0]), StepAction(verb="close", noun=nouns[0])],
        count=len(held), total=m, exceptions=[seg for _, seg, _ in other][:10],
        evidence=[seg for _, seg, _ in held][:20], tasks=sorted(ts), videos=videos_of(list(ts.values())),
        detail={"way": way, "closed": n, "opened": m, "prompt": prompt})

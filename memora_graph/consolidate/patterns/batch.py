"""Batch or one at a time: fetches one utensil as needed, or lays out a set first; carries one
leaf to the bin at a time, or gathers a handful first.

Rule, within each task:
- **fetches** are takes from storage (a cupboard, drawer, fridge, shelf). A run of at least
  `BATCH` fetches with only opening, closing or putting down between them is a set laid out
  first; a task with two or more fetches, each on its own, fetches one at a time as needed.
- **carries**: an object kind taken at least twice in a task is handled one at a time when each
  take is followed by putting it somewhere before the next, in a batch when `BATCH` takes come in a
  row (a handful gathered) or two or more takes in a row are followed by two or more puts in a row
  (gathered, then put down together). Two takes in a row put down one by one are a re-grasp or a
  portion at a time and count neither way.
Counted over tasks; a record needs `MIN_TASKS` tasks and says which way wins, with the other
way's count (its exceptions).
"""

from __future__ import annotations

import re
from collections import defaultdict

from memora_graph.consolidate import vocab
from memora_graph.consolidate.patterns._common import MIN_TASKS, obj, top, videos_of
from memora_graph.consolidate.records import StepAction
from memora_graph.consolidate.task_records import Task, TaskPattern

BATCH = 3
STORE_WORDS = ("cupboard", "drawer", "fridge", "shelf", "cabinet", "freezer", "pantry")


def _from_storage(place: str) -> bool:
    return any(w in (place or "") for w in STORE_WORDS)


def _fetch_runs(t: Task):
    """Runs of fetches from storage: (one_at_a_time, nouns, segments) per run. A run is fetches with
    nothing but opening, closing or more fetching between them."""
    steps, out, i = t.steps, [], 0
    while i < len(steps):
        a = steps[i].action
        if a.verb not in vocab.TAKING or not a.noun or not _from_storage(a.place):
            i += 1
            continue
        nouns, segs, j = [a.noun], [steps[i].segment], i + 1
        while j < len(steps):
            b = steps[j].action
            if b.verb in vocab.TAKING and b.noun and _from_storage(b.place):
                nouns.append(b.noun)
                segs.append(steps[j].segment)
            elif b.verb not in ("open", "close", "hold", "move", "put"):
                break
            j += 1
        out.append((len(nouns) < BATCH, nouns, segs))
        i = j
    return out


def _carries(t: Task):
    """Per object kind taken at least twice in the task: 'one' when each take is followed by putting
    it somewhere before the next take, 'batch' when two takes of it come in a row."""
    seq: dict[str, list[tuple[str, str]]] = defaultdict(list)
    for s in t.steps:
        a = s.action
        if a.noun and (a.verb in vocab.TAKING or a.verb in vocab.RELEASING):
            seq[a.noun].append(("take" if a.verb in vocab.TAKING else "put", s.segment))
    out = []
    for noun, evs in seq.items():
        takes = [e for e in evs if e[0] == "take"]
        if len(takes) < 2:
            continue
        ways = "".join("t" if e[0] == "take" else "p" for e in evs)
        if "tt" not in ways:
            out.append((True, noun, [seg for _, seg in takes]))
        elif re.search(r"t{%d}|tt+pp" % BATCH, ways):  # gathered (a handful, or several put down together)
            out.append((False, noun, [seg for _, seg in takes]))
        # takes in a row put down one by one, or never: a re-grasp or a portion at a time, neither way
    return out


def detect(tasks: list[Task]) -> list[TaskPattern]:
    tally: dict[tuple[str, str], dict[bool, list[tuple[Task, list[str], list[str]]]]] = defaultdict(lambda: {True: [], False: []})
    for t in tasks:
        runs = _fetch_runs(t)
        singles = [(n, s) for single, n, s in runs if single]
        for single, nouns, segs in runs:
            if not single:
                tally[("fetch", "*")][False].append((t, nouns, segs))
        if len(singles) >= 2:  # fetched several things, each when needed
            tally[("fetch", "*")][True].append((t, [n for ns, _ in singles for n in ns], [x for _, ss in singles for x in ss]))
        for single, noun, segs in _carries(t):
            tally[("carry", noun)][single].append((t, [noun], segs))
    out = []
    for (kind, noun), ways in tally.items():
        one, many = ways[True], ways[False]
        n1, nb = len({t.id for t, _, _ in one}), len({t.id for t, _, _ in many})
        if max(n1, nb) < MIN_TASKS:
            continue
        single = n1 >= nb
        win, lose = (one, many) if single else (many, one)
        kinds = list(dict.fromkeys(k for _, ns, _ in win for k in ns))
        if kind == "fetch":
            statement = (f"Retrieves things from storage one at a time as the task requires, rather than laying out a set "
                         f"first ({n1} of {n1 + nb} tasks)" if single else
                         f"Lays out a set of things from storage first, then works with them "
                         f"({', '.join(obj(k) for k in kinds[:5])}; {nb} of {n1 + nb} tasks)")
        else:
            statement = (f"Handles the {obj(noun)} one at a time: takes one, puts it where it goes, then returns for the "
                         f"next ({n1} of {n1 + nb} tasks)" if single else
                         f"Gathers several {obj(noun)} together first, then puts them down together "
                         f"({nb} of {n1 + nb} tasks)")
        out.append(TaskPattern(
            family="batch", key=(kind, noun, "one" if single else "batch"),
            statement=statement, objects=kinds[:8],
            actions=[StepAction(verb="take", noun=k) for k in kinds[:4]],
            count=max(n1, nb), total=n1 + nb, evidence=[s for _, _, ss in win for s in ss][:20],
            exceptions=[s for _, _, ss in lose for s in ss][:10], tasks=sorted({t.id for t, _, _ in win}),
            videos=videos_of([o[0] for o in win]), detail={"way": "one_at_a_time" if single else "batch", "kind": kind,
                                         "one_at_a_time": n1, "batch": nb}))
    return top(out)


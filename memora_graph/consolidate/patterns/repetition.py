"""Repetition and alternation: "alternates stretching and folding the dough in repeated passes";
"rinses the cloth, wipes the sink, rinses the cloth again".

Rule: within a task, the sequence of work verbs (not take/put bookkeeping) done to each object
kind, or around it (the steps between two steps on it). An **alternation** is two verbs a, b
following each other as a b a b (at least `CYCLES` full cycles, other steps allowed between); a
**repetition** is one verb done to the object in at least `PASSES` separate passes. Counted over
tasks; a record needs `MIN_TASKS` tasks, or a single task with twice the cycles.
"""

from __future__ import annotations

from collections import defaultdict

from memora_graph.consolidate import vocab
from memora_graph.consolidate.patterns._common import MIN_TASKS, obj, top, videos_of, with_object
from memora_graph.consolidate.records import StepAction
from memora_graph.consolidate.task_records import Task, TaskPattern

CYCLES = 2
PASSES = 3


def _collapse(seq: list[tuple[str, str]]) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    for v, seg in seq:
        if not out or out[-1][0] != v:
            out.append((v, seg))
    return out


def _cycles(seq: list[str], a: str, b: str) -> int:
    n, want, half = 0, a, 0
    for v in seq:
        if v == want:
            half += 1
            want = b if want == a else a
            if half % 2 == 0:
                n += 1
    return n


def detect(tasks: list[Task]) -> list[TaskPattern]:
    alt: dict[tuple, list[tuple[Task, int, list[str]]]] = defaultdict(list)
    rep: dict[tuple, list[tuple[Task, int, list[str]]]] = defaultdict(list)
    for t in tasks:
        per: dict[str, list[tuple[str, str]]] = defaultdict(list)
        for s in t.steps:
            a = s.action
            if a.noun and a.verb not in vocab.FILLER:
                per[a.noun].append((a.verb, s.segment))
                if a.instrument:
                    per[a.instrument].append((a.verb, s.segment))
        for noun, seq in per.items():
            col = _collapse(seq)
            verbs = [v for v, _ in col]
            segs = list(dict.fromkeys(s for _, s in col))
            pairs = {(verbs[i], verbs[i + 1]) for i in range(len(verbs) - 1)}
            for a, b in pairs:
                if a < b and (b, a) in pairs:
                    c = _cycles(verbs, a, b) if verbs.index(a) < verbs.index(b) else _cycles(verbs, b, a)
                    if c >= CYCLES:
                        first, second = (a, b) if verbs.index(a) < verbs.index(b) else (b, a)
                        alt[(noun, first, second)].append((t, c, segs))
            passes = defaultdict(int)
            for v in verbs:
                passes[v] += 1
            for v, c in passes.items():
                if c >= PASSES:
                    rep[(noun, v)].append((t, c, segs))
    out = []
    handling = with_object(tasks)
    for (noun, a, b), occ in alt.items():
        n, cycles = len({t.id for t, _, _ in occ}), sum(c for _, c, _ in occ)
        if n < MIN_TASKS and cycles < 2 * CYCLES:
            continue
        with_obj = handling[noun]
        out.append(TaskPattern(
            family="repetition", key=("alternate", noun, a, b),
            statement=f"Alternates {vocab.gerund(a)} and {vocab.gerund(b)} the {obj(noun)} in repeated passes "
                      f"({cycles} cycles in {n} tasks)",
            objects=[noun], actions=[StepAction(verb=a, noun=noun), StepAction(verb=b, noun=noun)],
            count=n, total=max(n, with_obj), evidence=[s for _, _, ss in occ for s in ss][:20],
            tasks=sorted({t.id for t, _, _ in occ}), videos=videos_of([o[0] for o in occ]), detail={"cycles": cycles, "way": "alternate"}))
    for (noun, v), occ in rep.items():
        n, passes = len({t.id for t, _, _ in occ}), sum(c for _, c, _ in occ)
        if n < MIN_TASKS:
            continue
        with_obj = handling[noun]
        out.append(TaskPattern(
            family="repetition", key=("repeat", noun, v),
            statement=f"{vocab.third_person(vocab.phrase(v)).capitalize()} the {obj(noun)} in several passes, coming back "
                      f"to it again ({passes} passes in {n} tasks)",
            objects=[noun], actions=[StepAction(verb=v, noun=noun)], count=n, total=max(n, with_obj),
            evidence=[s for _, _, ss in occ for s in ss][:20], tasks=sorted({t.id for t, _, _ in occ}),
            videos=videos_of([o[0] for o in occ]), detail={"passes": passes, "way": "repeat"}))
    return top(out)


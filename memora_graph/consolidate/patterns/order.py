"""Order invariants: "empties the saucepan before washing it (4 of 5 times)".

Rule: within each task, the first and last time each action (verb class) is done to an object
kind. For every pair of actions on the same object in one task, whether one was over before the
other began (interleaved pairs, a b a, say nothing about order: see `repetition`). A pair whose order held
in at least `MIN_SHARE` of the tasks where both occur, over at least `MIN_TASKS` tasks, is an
invariant; the tasks where it was reversed are its exceptions. Bookkeeping verbs that say
nothing about method (hold, move, let go) are left out, and so are pairs of two bookkeeping
verbs (take, put, ...), which order every task the same way.
"""

from __future__ import annotations

from collections import defaultdict

from memora_graph.consolidate import vocab
from memora_graph.consolidate.patterns._common import MIN_TASKS, obj, top, verb3
from memora_graph.consolidate.records import StepAction
from memora_graph.consolidate.task_records import Task, TaskPattern

MIN_SHARE = 0.75
IGNORED = frozenset({"hold", "move", "let-go", "transition", "carry", "look", "search", "choose", "turn"})
# taking and putting down frame every action ("takes the knife before washing it" says nothing),
# and an action's own undoing follows it by definition
BOOKKEEPING = vocab.TAKING | vocab.RELEASING
INVERSE = frozenset({("turn-on", "turn-off"), ("open", "close"), ("turn-off", "turn-on"), ("close", "open")})


def detect(tasks: list[Task]) -> list[TaskPattern]:
    held: dict[tuple, list[tuple[Task, str]]] = defaultdict(list)
    for t in tasks:
        first: dict[tuple[str, str], tuple[float, str]] = {}
        last: dict[tuple[str, str], float] = {}
        for s in t.steps:
            a = s.action
            if a.verb in IGNORED or not a.noun:
                continue
            first.setdefault((a.noun, a.verb), (s.t, s.segment))
            last[(a.noun, a.verb)] = s.t
        by_obj: dict[str, list[tuple[float, str, str]]] = defaultdict(list)
        for (noun, verb), (tt, seg) in first.items():
            by_obj[noun].append((tt, verb, seg))
        for noun, acts in by_obj.items():
            acts.sort()
            for i, (ta, va, sa) in enumerate(acts):
                for tb, vb, sb in acts[i + 1:]:
                    if va in BOOKKEEPING or vb in BOOKKEEPING or (va, vb) in INVERSE or ta == tb:
                        continue
                    if last[(noun, va)] > tb:  # interleaved (a b a): no order, a repetition's business
                        continue
                    held[(noun, va, vb)].append((t, sa))
    out = []
    for (noun, va, vb), occ in held.items():
        rev = held.get((noun, vb, va), [])
        n, m = len({t.id for t, _ in occ}), len({t.id for t, _ in occ} | {t.id for t, _ in rev})
        if n < MIN_TASKS or n / m < MIN_SHARE:
            continue
        o = obj(noun)
        ts = [t for t, _ in occ]
        vids: dict[str, int] = {}
        for t in ts:
            vids[t.video] = vids.get(t.video, 0) + 1
        out.append(TaskPattern(
            family="order", key=(noun, va, vb),
            statement=f"{verb3(vocab.phrase(va)).capitalize()} the {o} before {vocab.gerund(vb).replace(' ', ' it ', 1) if ' ' in vocab.gerund(vb) else vocab.gerund(vb) + ' it'} ({n} of {m} times)",
            objects=[noun], actions=[StepAction(verb=va, noun=noun), StepAction(verb=vb, noun=noun)],
            count=n, total=m, exceptions=[s for _, s in rev][:10], evidence=[s for _, s in occ][:20],
            tasks=sorted({t.id for t in ts}), videos=dict(sorted(vids.items())),
            detail={"first": va, "then": vb}))
    return top(out)

"""Canonical stages and steps of a recurring task, with their variants.

Rule: for each goal done at least `MIN_TASKS` times, its (verb, object) steps. A step found in at
least `MIN_SHARE` of the occurrences is canonical; those in fewer (but at least two) are variants.
A canonical step belongs to the stage it is in most often (a filter folded before the coffee is
spooned is setup in one morning and main in the next: one step, counted once per occurrence).
Steps are ordered by their median position (0-1) within the task. The record states the stages
in order ("setup: open fridge, take egg; main: crack egg, stir egg; ...").
"""

from __future__ import annotations

from collections import Counter, defaultdict
from statistics import median

from memora_graph.consolidate import vocab
from memora_graph.consolidate.patterns._common import MIN_TASKS, obj, recurring, top, videos_of
from memora_graph.consolidate.records import StepAction
from memora_graph.consolidate.task_records import Task, TaskPattern

MIN_SHARE = 0.5
STAGES = ("setup", "main", "finish", "cleanup")
MAX_STEPS = 5  # canonical steps per stage


def stages_of(ts: list[Task]) -> tuple[dict[str, list[tuple[str, str, float]]], list[tuple[str, str]]]:
    """stage -> canonical (verb, noun, median position) in order; and the variants."""
    pos: dict[tuple[str, str], dict[str, float]] = defaultdict(dict)
    stage: dict[tuple[str, str], Counter] = defaultdict(Counter)
    for t in ts:
        n = max(1, len(t.steps) - 1)
        for i, s in enumerate(t.steps):
            if s.action.noun and s.action.verb not in ("hold", "move", "let-go"):
                key = (s.action.verb, s.action.noun)
                if t.id not in pos[key]:
                    pos[key][t.id] = i / n
                    stage[key][s.stage] += 1
    canon: dict[str, list[tuple[str, str, float]]] = {st: [] for st in STAGES}
    variants = []
    for (v, o), by_task in pos.items():
        share = len(by_task) / len(ts)
        if share >= MIN_SHARE and len(by_task) >= MIN_TASKS:
            st = max(STAGES, key=lambda x: stage[(v, o)][x])  # most often; the earlier stage on a tie
            canon[st].append((v, o, median(by_task.values())))
        elif len(by_task) >= 2:
            variants.append((v, o))
    for st in STAGES:
        canon[st] = sorted(canon[st], key=lambda x: x[2])[:MAX_STEPS]
    return canon, sorted(set(variants))[:8]


def detect(tasks: list[Task]) -> list[TaskPattern]:
    out = []
    for goal, ts in recurring(tasks).items():
        canon, variants = stages_of(ts)
        steps = [(st, v, o) for st in STAGES for v, o, _ in canon[st]]
        if len(steps) < 2:
            continue
        said = "; ".join(f"{st}: " + ", ".join(f"{vocab.phrase(v)} {obj(o)}" for v, o, _ in canon[st])
                         for st in STAGES if canon[st])
        var = f"; variants: {', '.join(f'{vocab.phrase(v)} {obj(o)}' for v, o in variants[:4])}" if variants else ""
        out.append(TaskPattern(
            family="canonical", key=("goal", goal), goal=goal,
            statement=f"How {goal} is done ({len(ts)} times): {said}{var}",
            objects=list(dict.fromkeys(o for _, _, o in steps)),
            actions=[StepAction(verb=v, noun=o) for _, v, o in steps], count=len(ts), total=len(ts),
            evidence=[t.segments[0] for t in ts][:20], tasks=[t.id for t in ts], videos=videos_of(ts),
            detail={"stages": {st: [f"{vocab.phrase(v)} {obj(o)}" for v, o, _ in canon[st]] for st in STAGES},
                    "variants": [f"{vocab.phrase(v)} {obj(o)}" for v, o in variants]}))
    return top(out)

"""Set up before the main step: "before cooking the egg, opens the fridge and takes out the eggs".

Rule: for each recurring task (same goal at least `MIN_TASKS` times), the actions of its setup
stage (the steps before its first main-family step) as (verb, object). An action found in the
setup of at least `MIN_SHARE` of the occurrences is set up first; the occurrences without it are
the exceptions. Also across every task: an object prepared (opened, turned on, filled, fetched)
before the main step in `MIN_SHARE` of the tasks that use it, over `MIN_TASKS` tasks.
"""

from __future__ import annotations

from collections import Counter, defaultdict

from memora_graph.consolidate import vocab
from memora_graph.consolidate.patterns._common import MIN_TASKS, obj, recurring, top, videos_of
from memora_graph.consolidate.records import StepAction
from memora_graph.consolidate.task_records import Task, TaskPattern

MIN_SHARE = 0.5
PREPARING = frozenset({"open", "turn-on", "fill", "take", "remove", "put", "wash", "rinse", "wipe", "press", "adjust",
                       "check", "measure", "insert", "unwrap", "uncover", "switch"})


def _setup(t: Task) -> dict[tuple[str, str], str]:
    out: dict[tuple[str, str], str] = {}
    for s in t.steps:
        if s.stage != "setup":
            break
        if s.action.noun:
            out.setdefault((s.action.verb, s.action.noun), s.segment)
    return out


def _main(t: Task) -> str:
    m = next((s for s in t.steps if s.stage == "main"), None)
    return f"{vocab.gerund(m.action.verb)} the {obj(m.action.noun)}" if m and m.action.noun else t.goal


def detect(tasks: list[Task]) -> list[TaskPattern]:
    out = []
    for goal, ts in recurring(tasks).items():
        seen: dict[tuple[str, str], list[tuple[Task, str]]] = defaultdict(list)
        for t in ts:
            for k, seg in _setup(t).items():
                seen[k].append((t, seg))
        common = [(k, occ) for k, occ in seen.items() if len(occ) >= MIN_TASKS and len(occ) / len(ts) >= MIN_SHARE]
        if not common:
            continue
        common.sort(key=lambda x: (-len(x[1]), x[0]))
        common = common[:4]
        n = min(len(occ) for _, occ in common)
        said = ", then ".join(f"{vocab.third_person(vocab.phrase(v))} the {obj(o)}" for (v, o), _ in common)
        held = {t.id for _, occ in common for t, _ in occ}
        out.append(TaskPattern(
            family="setup", key=("goal", goal), goal=goal,
            statement=f"Before the main work of {goal} ({_main(ts[0])}), sets up first: {said} "
                      f"({n} of {len(ts)} times)",
            objects=list(dict.fromkeys(o for (_, o), _ in common)),
            actions=[StepAction(verb=v, noun=o) for (v, o), _ in common], count=n, total=len(ts),
            evidence=[s for _, occ in common for _, s in occ][:20],
            exceptions=[t.segments[0] for t in ts if t.id not in held][:10], tasks=sorted(held),
            videos=videos_of([t for t in ts if t.id in held])))
    # across tasks: objects made ready before the main step
    ready: dict[tuple[str, str], list[tuple[Task, str]]] = defaultdict(list)
    for t in tasks:
        for (v, o), seg in _setup(t).items():
            if v in PREPARING and v not in vocab.TAKING and v != "put":
                ready[(v, o)].append((t, seg))
    handled = {t.id: {s.action.noun for s in t.steps} for t in tasks}
    using_n = Counter(o for t in tasks for o in handled[t.id])  # o -> tasks handling it, counted once
    for (v, o), occ in ready.items():
        using = using_n[o]
        n = len({t.id for t, _ in occ})
        if n < MIN_TASKS or n / max(1, using) < MIN_SHARE:
            continue
        out.append(TaskPattern(
            family="setup", key=("object", v, o),
            statement=f"{vocab.third_person(vocab.phrase(v)).capitalize()} the {obj(o)} before starting the main step "
                      f"of the task ({n} of {using} tasks with it)",
            objects=[o], actions=[StepAction(verb=v, noun=o)], count=n, total=max(n, using),
            evidence=[s for _, s in occ][:20], tasks=sorted({t.id for t, _ in occ}), videos=videos_of([t for t, _ in occ])))
    return top(out)

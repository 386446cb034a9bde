"""Which tool or container carries a transfer: "fills the jug at the tap and pours it into the
kettle", "scoops the rice with a spoon", or moves the food in the pot itself.

Rule: a transfer is a step that moves a substance or food into something (pour, scoop, fill,
empty, add, insert into a container; a step with a destination or a second object). Its
carrier is the tool named in the step (a spoon, a ladle), else the container the substance was
last filled or taken in within the task before it (a jug filled at the tap), else the substance's
own container ("directly"). Counted per (substance, destination); the winning carrier needs
`MIN_TASKS` tasks; the others are the alternatives.
"""

from __future__ import annotations

from collections import Counter, defaultdict

from memora_graph.consolidate import vocab
from memora_graph.consolidate.patterns._common import MIN_TASKS, obj, top, videos_of
from memora_graph.consolidate.records import StepAction
from memora_graph.consolidate.task_records import Task, TaskPattern

TRANSFER = frozenset({"pour", "scoop", "fill", "empty", "add", "sprinkle", "spread"})
CONTAINERS = frozenset({"jug", "cup", "glass", "bowl", "pan", "pot", "saucepan", "kettle", "bottle", "mug", "container",
                        "jar", "tray", "plate", "colander", "ladle", "spoon", "scoop", "measuring:cup"})


def detect(tasks: list[Task]) -> list[TaskPattern]:
    seen: dict[tuple[str, str], list[tuple[Task, str, str]]] = defaultdict(list)
    for t in tasks:
        last_vessel = ""
        for s in t.steps:
            a = s.action
            if a.verb in ("fill", "take") and a.noun in CONTAINERS:
                last_vessel = a.noun
            if a.verb not in TRANSFER or not a.noun:
                continue
            dest = a.place if a.place and a.place != a.noun else ""
            if not dest:
                continue
            tool = a.instrument if a.instrument not in (a.noun, dest) else ""
            carrier = tool or (last_vessel if last_vessel and last_vessel not in (a.noun, dest) else "directly")
            seen[(a.noun, dest)].append((t, carrier, s.segment))
    out = []
    for (noun, dest), occ in seen.items():
        by = Counter(c for _, c, _ in occ)
        carrier, n = by.most_common(1)[0]
        tasks_n = len({t.id for t, c, _ in occ if c == carrier})
        if tasks_n < MIN_TASKS:
            continue
        how = (f"straight from the {obj(noun)}" if carrier == "directly" else f"with the {obj(carrier)}")
        out.append(TaskPattern(
            family="carrier", key=(noun, dest, carrier),
            statement=f"Transfers the {obj(noun)} into the {dest} {how} ({n} of {len(occ)} times)",
            objects=[noun] + ([carrier] if carrier != "directly" else []),
            actions=[StepAction(verb="pour", noun=noun, place=dest, instrument="" if carrier == "directly" else carrier)],
            count=n, total=len(occ), evidence=[s for _, c, s in occ if c == carrier][:20],
            exceptions=[s for _, c, s in occ if c != carrier][:10], tasks=sorted({t.id for t, c, _ in occ if c == carrier}),
            videos=videos_of([t for t, c, _ in occ if c == carrier]),
            detail={"carrier": carrier, "alternatives": {k: v for k, v in by.items() if k != carrier}}))
    return top(out)


"""Tasks: each video's activity cut into stretches of steps that serve one goal, named by goal,
with stages (setup / main / finish / cleanup), objects, tools, places and evidence segments.

Deterministic, from the typed steps alone (`consolidate.memory.MemoryStep`):

1. **Cut** between two steps when
   - there is a pause of more than `PAUSE` seconds, or
   - the person moves to another place and the objects of the next `AHEAD` steps share nothing
     with the objects of the last `BEHIND` steps (object-set continuity breaks).
   A piece shorter than `MIN_STEPS` steps joins the task before it (the first one the task after).
2. **Name** by the dominant verb family (cleanup, cooking, prep, setup; else storing things away)
   and the object the family's steps handle most: "wash up saucepan", "cook egg", "prepare onion",
   "put away milk". A task whose objects include a drink or dish it produces is named after it
   ("make coffee", "make tea", "make toast").
3. **Stages**: `main` runs from the first to the last step of the dominant family (of a task named
   after its product, from the first to the last step handling the product); steps before it
   are `setup`; after it, from the first cleanup step (a cleanup verb, or something thrown away or
   put back in storage) on, `cleanup`, and the rest `finish`.

Ids are stable across rebuilds: participant + video + first segment (+ an ordinal when a segment
starts two tasks).
"""

from __future__ import annotations

from collections import Counter

from memora_graph.consolidate import vocab
from memora_graph.consolidate.memory import MemoryStep, ParticipantMemory, display
from memora_graph.consolidate.task_records import Task, TaskStep

PAUSE = 40.0  # seconds without a step: a new task
AHEAD, BEHIND = 4, 8  # steps compared for object-set continuity
MIN_STEPS = 4  # a shorter piece is not a task of its own
# What a task produces, named after its product when one of these is handled.
PRODUCTS = {"coffee": "make coffee", "tea": "make tea", "teabag": "make tea", "toast": "make toast",
            "toaster": "make toast", "sandwich": "make a sandwich", "salad": "prepare a salad",
            "omelette": "make an omelette", "pasta": "cook pasta", "rice": "cook rice", "porridge": "make porridge",
            "smoothie": "make a smoothie", "cereal": "have cereal", "washing:machine": "load the washing machine"}
FAMILY_VERB = {"cleanup": "wash up", "cooking": "cook", "prep": "prepare", "setup": "set up", "store": "put away"}
STORAGE = vocab.STORAGE_KINDS | {"bin", "rubbish", "trash"}


def _objects(s: MemoryStep) -> list[str]:
    return [o.kind for o in s.objects if not o.is_fixture]


def _is_tool(category: str) -> bool:
    return category in vocab.TOOL_CATEGORIES


def cut(steps: list[MemoryStep]) -> list[list[MemoryStep]]:
    """A video's steps (in time order) cut into tasks (rule 1)."""
    pieces: list[list[MemoryStep]] = []
    cur: list[MemoryStep] = []
    for i, s in enumerate(steps):
        if cur:
            prev = cur[-1]
            pause = s.t - prev.t > PAUSE
            moved = s.location != prev.location
            behind = {k for x in cur[-BEHIND:] for k in _objects(x)}
            ahead = {k for x in steps[i:i + AHEAD] for k in _objects(x)}
            if pause or (moved and behind and ahead and not (behind & ahead)):
                pieces.append(cur)
                cur = []
        cur.append(s)
    if cur:
        pieces.append(cur)
    out: list[list[MemoryStep]] = []
    for p in pieces:
        if out and len(p) < MIN_STEPS:
            out[-1].extend(p)
        elif out and len(out[-1]) < MIN_STEPS:
            out[-1].extend(p)
        else:
            out.append(list(p))
    return out


def _family(steps: list[MemoryStep]) -> str:
    fam = Counter(vocab.category(s.verb) for s in steps if vocab.category(s.verb))
    if not fam:
        return "store"
    best, n = fam.most_common(1)[0]
    # setup verbs (turn on, check) rarely make the goal when work verbs are there
    if best == "setup" and len(fam) > 1:
        best = next(f for f, _ in fam.most_common() if f != "setup")
    return best


def _stage(steps: list[MemoryStep], family: str, product: str | None = None) -> list[str]:
    if product:  # a task named after its product: the main work is what is done with the product
        fam_idx = [i for i, s in enumerate(steps) if product in _objects(s)]
    else:
        fam_idx = [i for i, s in enumerate(steps) if (vocab.category(s.verb) or "store") == family
                   or (family == "store" and s.verb in vocab.RELEASING)]
    first, last = (fam_idx[0], fam_idx[-1]) if fam_idx else (0, len(steps) - 1)
    out = []
    cleanup_started = False
    for i, s in enumerate(steps):
        if i < first:
            out.append("setup")
        elif i <= last:
            out.append("main")
        else:
            if not cleanup_started and family != "cleanup" and (
                    vocab.category(s.verb) == "cleanup" or (s.destination in STORAGE and s.verb in vocab.RELEASING)):
                cleanup_started = True
            out.append("cleanup" if cleanup_started else "finish")
    return out


def _product(steps: list[MemoryStep]) -> str | None:
    kinds = {k for s in steps for k in _objects(s)}
    return next((k for k in PRODUCTS if k in kinds), None)


def _goal(steps: list[MemoryStep], family: str, main: str) -> str:
    product = _product(steps)
    return PRODUCTS[product] if product else f"{FAMILY_VERB[family]} {display(main)}".strip()


def make_task(participant: str, steps: list[MemoryStep], nth: int = 0) -> Task:
    from memora_graph.consolidate.rules import stable_id

    family = _family(steps)
    work = [s for s in steps if (vocab.category(s.verb) or "store") == family] or steps
    counts = Counter(o.kind for s in work for o in s.objects[:1] if not o.is_fixture and not _is_tool(o.category))
    if not counts:
        counts = Counter(o.kind for s in steps for o in s.objects if not o.is_fixture)
    main = counts.most_common(1)[0][0] if counts else steps[0].main.kind
    stages = _stage(steps, family, _product(steps))
    everything = Counter(o.kind for s in steps for o in s.objects if not o.is_fixture)
    tools = list(dict.fromkeys(o.kind for s in steps for o in s.objects if _is_tool(o.category)))
    out_steps = []
    for s, st in zip(steps, stages):
        a = s.action()
        inst = next((o.kind for o in s.objects[1:] if _is_tool(o.category)), "")
        if inst:
            a = a.model_copy(update={"instrument": inst})
        out_steps.append(TaskStep(action=a, stage=st, t=round(s.t, 2), segment=s.segment, text=s.text()))
    return Task(
        id=stable_id(participant, "task", steps[0].video, steps[0].segment, *([nth] if nth else [])),
        video=steps[0].video, goal=_goal(steps, family, main), family=family, main_object=main,
        t_start=round(steps[0].t, 2), t_end=round(steps[-1].t, 2), steps=out_steps,
        objects=[k for k, _ in everything.most_common()], tools=tools,
        places=list(dict.fromkeys(s.location for s in steps if s.location)),
        segments=list(dict.fromkeys(s.segment for s in steps)),
        entities=list(dict.fromkeys(o.entity for s in steps for o in s.objects)),
    )


def video_tasks(participant: str, steps: list[MemoryStep]) -> list[Task]:
    steps = sorted(steps, key=lambda s: s.t)
    out, seen = [], Counter()
    for p in cut(steps):
        out.append(make_task(participant, p, seen[p[0].segment]))  # a second task starting in one segment: its ordinal
        seen[p[0].segment] += 1
    return out


def segment_tasks(memory: ParticipantMemory) -> list[Task]:
    """Every video's tasks, videos in order."""
    by_video = memory.steps_by_video()
    out: list[Task] = []
    for v in memory.videos:
        steps = list(by_video.get(v) or [])  # one read: a step table makes a video's steps per read
        if steps:
            out += video_tasks(memory.participant, steps)
    return out

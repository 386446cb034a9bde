"""Tasks: each video's activity cut into stretches of steps that serve one goal, named by goal,
with stages (setup / main / finish / cleanup), objects, tools, places and evidence segments.

Deterministic, from the typed steps alone (`consolidate.memory.MemoryStep`):

1. **Cut** between two steps when
   - there is a pause of more than `PAUSE` seconds, or
   - the person moves to another place and the objects of the next `AHEAD` steps share nothing
     with the objects of the last `BEHIND` steps (object-set continuity breaks), or
   - the kind of work changes (verb families): each work step is labelled clean / prep / cook /
     eat by its verb, each label is smoothed to the majority of the `WINDOW` work steps around it,
     and where a run of one label (at least `MIN_RUN` work steps) follows a run of another, the
     task is cut before the new run, together with the steps just before it that fetch the new
     run's objects or work a fixture (turn on the tap before washing up).
   A piece shorter than `MIN_STEPS` steps joins the task before it (the first one the task after).
   Consecutive pieces that rule 2 names by one goal, with no pause between them, are one task
   (`join_same_goal`: "make coffee" cut where the person fetched a filter from another place).
2. **Name** by what the task produces, when it handles a product (coffee, tea, toast, boiled water:
   `PRODUCTS`) in at least `MIN_PRODUCT` of its steps, some product in at least `PRODUCT_SHARE` of
   them, and is no wash-up or put-away: the product handled most, boiled water only when nothing
   else is made (a tea boils water too): "make coffee", "make tea", "make toast", "boil water". Else by the dominant verb family and the
   object the family's steps handle most: "wash up saucepan", "prepare onion", "eat bread" (a
   wash-up of no object but a fixture, wiped with a cloth: "clean top"); a
   cooking task by its cooking verb when it is no plain "cook" ("fry egg", "pour oil"); a task
   that puts at least `MIN_GROCERIES` kinds of food away in storage "put away groceries", any
   other storing "put away milk".
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
from memora_graph.consolidate.task_records import CompactAction, CompactStep, CompactTask, Task

PAUSE = 40.0  # seconds without a step: a new task
AHEAD, BEHIND = 4, 8  # steps compared for object-set continuity
MIN_STEPS = 4  # a shorter piece is not a task of its own
WINDOW = 7  # work steps a step's work label is smoothed over
MIN_RUN = 4  # work steps of one label that make a task of their own
MIN_PRODUCT = 2  # steps handling a product for the task to be named after it ...
PRODUCT_SHARE = 0.1  # ... and at least this share of its steps (a kettle used once in an hour of baking is no tea)
MIN_GROCERIES = 3  # kinds of food put away in storage: "put away groceries"
# What a task produces, named after its product when one of these is handled; first the most telling
# (a tea task boils water too: it is named after the tea).
PRODUCTS = {"coffee": "make coffee", "coffee_maker": "make coffee", "tea": "make tea", "teabag": "make tea",
            "teapot": "make tea", "toast": "make toast", "toaster": "make toast", "sandwich": "make a sandwich",
            "salad": "prepare a salad", "omelette": "make an omelette", "pasta": "cook pasta", "rice": "cook rice",
            "porridge": "make porridge", "smoothie": "make a smoothie", "cereal": "have cereal",
            "washing:machine": "load the washing machine", "kettle": "boil water"}
FALLBACK_PRODUCT = "boil water"  # a sub-goal of making tea or coffee: the name only when nothing else is made
FAMILY_VERB = {"cleanup": "wash up", "cooking": "cook", "prep": "prepare", "setup": "set up", "store": "put away",
               "eat": "eat"}
EATING = frozenset({"eat", "drink"})  # verbs of the eat family (no cleanup / prep / cooking category)
FOOD = frozenset({"vegetables", "fruits and nuts", "dairy and eggs", "meat and substitute", "baked goods and grains",
                  "spices and herbs and sauces", "prepared food", "drinks"})  # object categories that are food
_LABEL = {"cleanup": "clean", "prep": "prep", "cooking": "cook"}
STORAGE = vocab.STORAGE_KINDS | {"bin", "rubbish", "trash"}


def _objects(s: MemoryStep) -> list[str]:
    return [o.kind for o in s.objects if not o.is_fixture]


def _is_tool(category: str) -> bool:
    return category in vocab.TOOL_CATEGORIES


def _label(s: MemoryStep) -> str | None:
    """The kind of work a step does (clean / prep / cook / eat), None for fetching and setting up."""
    if s.verb in EATING:
        return "eat"
    return _LABEL.get(vocab.category(s.verb) or "")


def _work_cuts(steps: list[MemoryStep]) -> set[int]:
    """Indices where the kind of work changes (rule 1, third case)."""
    work = [(i, lab) for i, s in enumerate(steps) if (lab := _label(s))]
    if len(work) < 2 * MIN_RUN:
        return set()
    half = WINDOW // 2
    smooth = []
    for j in range(len(work)):
        near = Counter(lab for _, lab in work[max(0, j - half):j + half + 1])
        top = max(near.values())
        smooth.append(work[j][1] if near[work[j][1]] == top else near.most_common(1)[0][0])
    runs: list[list[int]] = []  # [label index start, end) over `work`
    for j, lab in enumerate(smooth):
        if runs and smooth[runs[-1][0]] == lab:
            runs[-1][1] = j + 1
        else:
            runs.append([j, j + 1])
    long_runs = [r for r in runs if r[1] - r[0] >= MIN_RUN]
    cuts = set()
    for a, b in zip(long_runs, long_runs[1:]):
        if smooth[a[0]] == smooth[b[0]]:
            continue
        first = work[b[0]][0]
        ahead = {k for x in steps[first:first + AHEAD + 2] for k in _objects(x)}
        i = first
        lower = work[a[1] - 1][0] + 1  # never before the last step of the run before
        while i - 1 >= lower and not _label(steps[i - 1]) and (
                steps[i - 1].main.is_fixture or steps[i - 1].main.kind in ahead):
            i -= 1
        cuts.add(i)
    return cuts


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
    pieces = [q for p in pieces for q in _split(p)]
    out: list[list[MemoryStep]] = []
    for p in pieces:
        if out and len(p) < MIN_STEPS:
            out[-1].extend(p)
        elif out and len(out[-1]) < MIN_STEPS:
            out[-1].extend(p)
        else:
            out.append(list(p))
    return out


def _split(piece: list[MemoryStep]) -> list[list[MemoryStep]]:
    bounds = sorted(_work_cuts(piece) - {0})
    edges = [0, *bounds, len(piece)]
    return [piece[a:b] for a, b in zip(edges, edges[1:]) if b > a]


def _category(s: MemoryStep) -> str | None:
    return "eat" if s.verb in EATING else vocab.category(s.verb)


def _family(steps: list[MemoryStep]) -> str:
    fam = Counter(c for s in steps if (c := _category(s)))
    if not fam:
        return "store"
    best, n = fam.most_common(1)[0]
    # setup verbs (turn on, check) rarely make the goal when work verbs are there
    if best == "setup" and len(fam) > 1:
        best = next(f for f, _ in fam.most_common() if f != "setup")
    return best


def _stage(steps: list[MemoryStep], family: str, product: str | None = None) -> list[str]:
    if product:  # a task named after its product: the main work is what is done with the product
        kinds = {k for k, g in PRODUCTS.items() if g == PRODUCTS[product]}
        fam_idx = [i for i, s in enumerate(steps) if kinds & {*_objects(s), s.destination}]
    else:
        fam_idx = [i for i, s in enumerate(steps) if (_category(s) or "store") == family
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


def _product(steps: list[MemoryStep], family: str = "") -> str | None:
    """The product the task is named after (rule 2): of the `PRODUCTS` goals whose objects are
    handled in at least MIN_PRODUCT steps, the one handled in most (the first in `PRODUCTS` on a
    tie; boiling water only when nothing else is made), when some product is handled in at least
    PRODUCT_SHARE of the steps; none for a wash-up or a put-away."""
    if family in ("cleanup", "store"):
        return None
    per_goal = Counter()
    for s in steps:
        for g in {PRODUCTS[k] for k in _objects(s) + [s.destination] if k in PRODUCTS}:
            per_goal[g] += 1
    order = list(dict.fromkeys(PRODUCTS.values()))
    made = sorted((g for g, n in per_goal.items() if n >= MIN_PRODUCT), key=lambda g: (g == FALLBACK_PRODUCT,
                                                                                        -per_goal[g], order.index(g)))
    if not made or max(per_goal.values()) < PRODUCT_SHARE * len(steps):
        return None
    return next(k for k, g in PRODUCTS.items() if g == made[0])


def _groceries(steps: list[MemoryStep]) -> bool:
    """At least MIN_GROCERIES kinds of food put away in storage."""
    kinds = {s.main.kind for s in steps if s.verb in vocab.RELEASING and s.destination in vocab.STORAGE_KINDS
             and s.main.category in FOOD}
    return len(kinds) >= MIN_GROCERIES


def _goal(steps: list[MemoryStep], family: str, main: str) -> str:
    product = _product(steps, family)
    if product:
        return PRODUCTS[product]
    if family == "store" and _groceries(steps):
        return "put away groceries"
    verb = FAMILY_VERB[family]
    if family == "cooking":  # "fry egg", "pour oil": the cooking verb the task does most to its object
        verbs = Counter(s.verb for s in steps if s.main.kind == main and vocab.category(s.verb) == "cooking")
        if verbs and "cook" not in verbs:
            verb = vocab.phrase(verbs.most_common(1)[0][0])
    return f"{verb} {display(main)}".strip()


def _naming(steps: list[MemoryStep]) -> tuple[str, str, str]:
    """(family, main object, goal) of a task's steps (rule 2)."""
    family = _family(steps)
    work = [s for s in steps if (_category(s) or "store") == family] or steps
    counts = Counter(o.kind for s in work for o in s.objects[:1] if not o.is_fixture and not _is_tool(o.category))
    surface = ""
    if not counts and family == "cleanup":  # wiping the worktop with a cloth: the worktop is what is cleaned
        surface = next((k for k, _ in Counter(s.main.kind for s in work if s.main.is_fixture).most_common(1)), "")
    if not counts:
        counts = Counter(o.kind for s in steps for o in s.objects if not o.is_fixture)
    main = counts.most_common(1)[0][0] if counts else steps[0].main.kind
    return family, main, f"clean {display(surface)}" if surface else _goal(steps, family, main)


def make_task(participant: str, steps: list[MemoryStep], nth: int = 0, share: dict | None = None,
              naming: tuple[str, str, str] | None = None) -> CompactTask:
    """The task of `steps` (compact: its steps as tuples; `.record()` is the `Task`). `share`, if
    given, makes equal actions and texts one object each across the calls that pass it; `naming`,
    the steps' `_naming` when already computed (`join_same_goal`)."""
    from memora_graph.consolidate.rules import stable_id

    share = {} if share is None else share
    family, main, goal = naming or _naming(steps)
    stages = _stage(steps, family, _product(steps, family))
    everything = Counter(o.kind for s in steps for o in s.objects if not o.is_fixture)
    tools = list(dict.fromkeys(o.kind for s in steps for o in s.objects if _is_tool(o.category)))
    out_steps = []
    for s, st in zip(steps, stages):
        inst = next((o.kind for o in s.objects[1:] if _is_tool(o.category)), "")
        a = CompactAction(s.verb, s.main.kind, s.where()[0], inst)  # MemoryStep.action(), with its instrument
        a = share.setdefault(a, a)
        text = s.text()
        out_steps.append(CompactStep(a, st, round(s.t, 2), s.segment, share.setdefault(text, text)))
    return CompactTask(
        id=stable_id(participant, "task", steps[0].video, steps[0].segment, *([nth] if nth else [])),
        video=steps[0].video, goal=goal, family=family, main_object=main,
        t_start=round(steps[0].t, 2), t_end=round(steps[-1].t, 2), steps=out_steps,
        objects=[k for k, _ in everything.most_common()], tools=tools,
        places=list(dict.fromkeys(s.location for s in steps if s.location)),
        segments=list(dict.fromkeys(s.segment for s in steps)),
        entities=list(dict.fromkeys(o.entity for s in steps for o in s.objects)),
    )


def join_same_goal(pieces: list[list[MemoryStep]]) -> list[tuple[list[MemoryStep], tuple[str, str, str]]]:
    """Rule 1, last: consecutive pieces that serve one goal are one task, when no pause of more than
    `PAUSE` seconds lies between them ("make coffee" cut in two where the person fetched a filter
    from another place). The joined piece is named again, as a whole. Each piece comes with its
    `_naming` (family, main object, goal), which `make_task` takes as it is."""
    out: list[tuple[list[MemoryStep], tuple[str, str, str]]] = []
    for p in pieces:
        naming = _naming(p)
        if out and out[-1][1][2] == naming[2] and p[0].t - out[-1][0][-1].t <= PAUSE:
            joined = out[-1][0]
            joined.extend(p)
            out[-1] = (joined, _naming(joined))
        else:
            out.append((list(p), naming))
    return out


def compact_video_tasks(participant: str, steps: list[MemoryStep], share: dict | None = None) -> list[CompactTask]:
    """A video's tasks, compact (see `make_task`)."""
    steps = sorted(steps, key=lambda s: s.t)
    out, seen = [], Counter()
    for p, naming in join_same_goal(cut(steps)):
        out.append(make_task(participant, p, seen[p[0].segment], share, naming))  # a second task starting in one segment: its ordinal
        seen[p[0].segment] += 1
    return out


def video_tasks(participant: str, steps: list[MemoryStep]) -> list[Task]:
    """A video's tasks as `Task` records."""
    return [t.record() for t in compact_video_tasks(participant, steps)]


def segment_tasks(memory: ParticipantMemory) -> list[CompactTask]:
    """Every video's tasks, videos in order, compact: a batch run holds every task of the
    participant at once (read like `Task`s by the detectors and the writer)."""
    by_video = memory.steps_by_video()
    out: list[CompactTask] = []
    share: dict = {}
    for v in memory.videos:
        steps = list(by_video.get(v) or [])  # one read: a step table makes a video's steps per read
        if steps:
            out += compact_video_tasks(memory.participant, steps, share)
    return out

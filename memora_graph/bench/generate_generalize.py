"""Planning Generalize generation: transfer, composition and fully novel goals, rule-built.

- Transfer: an action family the participant performs often (>= 5 times) applied to an object
  they handle but were never seen doing that action to (<= 2 targets per action, <= 6 tasks).
- Composition: three gated templates whose parts the participant performs separately but never
  together on that object in one video.
- Fully novel: three fixed goals (set the table, clean the countertop, make a simple salad).

Reference steps come from per-family step templates grounded in the participant's objects: the
names they use in the annotations (their 'chopping board', 'drying rack'), with colour,
material and location from the bank's object registry when one is given, otherwise the place
the annotations show the object being taken from or put.
"""

from __future__ import annotations

import random
import re
from collections import Counter
from dataclasses import dataclass

from memora_graph.bench.behaviour import Behaviour, noun_text
from memora_graph.bench.generate_replay import match_object, registry_objects
from memora_graph.bench.tasks import GeneralizeTask, MatchedObject

VEGETABLES = frozenset({
    "onion", "potato", "pepper", "carrot", "tomato", "garlic", "mushroom", "aubergine", "cucumber",
    "courgette", "vegetable", "broccoli", "squash", "leek", "lettuce", "corn", "spring onion", "pak choi",
    "green bean", "spinach", "kale", "asparagus", "celery", "cabbage", "ginger", "chilli",
})
FRUIT = frozenset({
    "peach", "lemon", "banana", "lime", "orange", "avocado", "apple", "mango", "kiwi", "pear", "melon",
    "pineapple", "plum", "strawberry", "grape",
})
PEELABLE = frozenset({
    "onion", "potato", "carrot", "garlic", "cucumber", "courgette", "ginger", "banana", "orange", "apple",
    "mango", "kiwi", "pear", "avocado", "lemon", "lime", "aubergine", "squash",
})
CUTTABLE = VEGETABLES | FRUIT | frozenset({"bread", "cheese", "meat", "chicken", "sausage", "tofu", "fish", "cake", "pizza"})
DISHES = frozenset({"plate", "bowl", "cup", "glass", "mug", "pan", "pot", "lid", "jug", "tray", "chopping board", "colander", "spatula", "knife", "spoon", "fork"})
RINSEABLE = VEGETABLES | FRUIT | DISHES

FAMILIES = {
    # name: (annotated verb heads, plausible targets)
    "cutting": (frozenset({"cut", "slice", "chop", "dice", "halve"}), CUTTABLE),
    "peeling": (frozenset({"peel"}), PEELABLE),
    "rinsing": (frozenset({"rinse"}), RINSEABLE),
    "scrubbing": (frozenset({"scrub", "wash", "sponge", "clean", "lather"}), DISHES),
}
STIRRING = frozenset({"stir", "mix", "fry", "stir-fry", "flip"})

# fixture -> (EPIC noun keys the participant may use, name when they never do)
FIXTURES = {
    "board": (("board:chopping",), "cutting board"), "knife": (("knife",), "knife"),
    "peeler": (("peeler:potato",), "peeler"), "bowl": (("bowl",), "bowl"), "sink": (("sink",), "sink"),
    "tap": (("tap",), "tap"), "rack": (("rack:drying",), "drying rack"), "sponge": (("sponge",), "sponge"),
    "bin": (("bin", "rubbish"), "bin"), "pan": (("pan",), "frying pan"), "spatula": (("spatula",), "spatula"),
    "stove": (("hob",), "stove"), "plate": (("plate",), "plate"), "fork": (("fork",), "fork"),
    "cup": (("cup", "glass", "mug"), "cup"), "cloth": (("cloth", "towel"), "cloth"),
    "cupboard": (("cupboard",), "cupboard"),
}
_DISPLAY = {"top": "counter", "kitchen": "counter"}
_PREP = re.compile(r"^(on|in|at|inside|under|near|beside|by|above|next to)\s+(the\s+)?", re.I)
_DEFAULT_PLACE = "counter"
FIXED_PLACE_CATEGORIES = frozenset({"furniture", "storage", "appliances"})  # where things are kept, not a glass


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")


def _head(verb: str) -> str:
    return verb.split("-")[0]


class Grounder:
    """Names, descriptions and places of a participant's objects for reference steps."""

    def __init__(self, behaviour: Behaviour, registry: list[dict] | None):
        self.b = behaviour
        self.registry = sorted((o for _, o in registry_objects(registry)), key=lambda o: o.memory_id) if registry else []
        self.handled = Counter({n: ev.count for n, ev in behaviour.noun_evidence.items()})

    def fixture(self, kind: str) -> str:
        keys, default = FIXTURES[kind]
        used = [k for k in keys if self.handled.get(k)]
        if used:
            return noun_text(max(used, key=lambda k: (self.handled[k], k)))
        return default

    def _registry(self, name: str) -> MatchedObject | None:
        return match_object(name, self.registry) if self.registry else None

    def describe(self, name: str) -> str:
        """'green cucumber' with a registry match, else the plain name."""
        obj = self._registry(name)
        if obj is None:
            return name
        attrs = [a for a in (obj.color.strip(), obj.material.strip()) if a and a.lower() not in name.lower()]
        return " ".join(attrs + [name])

    def place(self, name: str, noun_key: str | None = None) -> str:
        obj = self._registry(name)
        if obj is not None and obj.location.strip():
            return _PREP.sub("", obj.location.strip()).replace("_", " ")
        for kind in ("take", "put"):
            places = {p: ev for p, ev in self.b.places.get((kind, noun_key or ""), {}).items()
                      if self.b.category(p) in FIXED_PLACE_CATEGORIES}
            if places:
                best = max(places.items(), key=lambda kv: (kv[1].count, kv[0]))[0]
                return _DISPLAY.get(best, noun_text(best))
        return _DEFAULT_PLACE

    def key_for(self, name: str) -> str | None:
        for key in self.handled:
            if noun_text(key) == name:
                return key
        return None


def _steps_cutting(g: Grounder, t: str) -> list[str]:
    T, board, knife, bowl = g.describe(t), g.describe(g.fixture("board")), g.describe(g.fixture("knife")), g.describe(g.fixture("bowl"))
    kplace = g.place(g.fixture("knife"), "knife")
    return [
        f"Pick up the {T} from the {g.place(t, g.key_for(t))}.",
        f"Place the {T} on the {board} on the {g.place(g.fixture('board'), 'board:chopping')}.",
        f"Pick up the {knife} from the {kplace}.",
        f"Hold the {T} steady with one hand on the {board}.",
        f"Cut the {T} into pieces with the {knife}.",
        f"Place the {knife} back on the {kplace}.",
        f"Transfer the cut {t} pieces to the {bowl}.",
    ]


def _steps_peeling(g: Grounder, t: str) -> list[str]:
    T, peeler = g.describe(t), g.describe(g.fixture("peeler"))
    return [
        f"Pick up the {T} from the {g.place(t, g.key_for(t))}.",
        f"Pick up the {peeler} from the {g.place(g.fixture('peeler'), 'peeler:potato')}.",
        f"Hold the {T} steady with one hand.",
        f"Peel the {T} skin with the {peeler}.",
        f"Rotate the {t} and continue peeling until fully peeled.",
        f"Place the peeled {t} on the {g.describe(g.fixture('board'))}.",
        f"Discard the peelings in the {g.describe(g.fixture('bin'))}.",
    ]


def _steps_rinsing_produce(g: Grounder, t: str) -> list[str]:
    tap, sink = g.describe(g.fixture("tap")), g.describe(g.fixture("sink"))
    return [
        f"Pick up the {g.describe(t)} from the {g.place(t, g.key_for(t))}.",
        f"Carry the {t} to the {sink}.",
        f"Turn on the {tap}.",
        f"Rinse the {t} under running water.",
        f"Turn off the {tap}.",
        f"Place the clean {t} on the {g.describe(g.fixture('rack'))}.",
    ]


def _steps_washing_dish(g: Grounder, t: str) -> list[str]:
    tap, sink, sponge = g.describe(g.fixture("tap")), g.describe(g.fixture("sink")), g.describe(g.fixture("sponge"))
    return [
        f"Pick up the {g.describe(t)} from the {g.place(t, g.key_for(t))}.",
        f"Carry the {t} to the {sink}.",
        f"Turn on the {tap}.",
        f"Apply dish soap to the {sponge}.",
        f"Scrub the {t} with the {sponge}.",
        f"Rinse the {t} under running water.",
        f"Turn off the {tap}.",
        f"Place the clean {t} on the {g.describe(g.fixture('rack'))}.",
    ]


def _steps_cook(g: Grounder, t: str) -> list[str]:
    stove, pan, spatula = g.describe(g.fixture("stove")), g.describe(g.fixture("pan")), g.describe(g.fixture("spatula"))
    return [
        f"Turn on the {stove} to medium heat.",
        f"Place the {pan} on the {stove}.",
        f"Transfer the cut {t} pieces into the {pan}.",
        f"Pick up the {spatula} from the {g.place(g.fixture('spatula'), 'spatula')}.",
        f"Stir-fry the {t} with the {spatula} until cooked.",
        f"Turn off the {stove}.",
    ]


def _transfer_query(pid: str, family: str, target: str) -> str:
    if family == "cutting":
        return f"Help {pid} cut the {target}."
    if family == "peeling":
        return f"Help {pid} peel the {target}."
    if family == "rinsing" and target in VEGETABLES | FRUIT:
        return f"Help {pid} wash the {target} before preparing it."
    return f"Help {pid} clean the {target}."


def _transfer_steps(g: Grounder, family: str, target: str) -> list[str]:
    if family == "cutting":
        return _steps_cutting(g, target)
    if family == "peeling":
        return _steps_peeling(g, target)
    if family == "rinsing" and target in VEGETABLES | FRUIT:
        return _steps_rinsing_produce(g, target)
    return _steps_washing_dish(g, target)


@dataclass
class GeneralizeConfig:
    min_action_count: int = 5
    targets_per_action: int = 2
    max_transfer: int = 6
    seed: int = 42


class GeneralizeBuilder:
    def __init__(self, behaviour: Behaviour, registry: list[dict] | None, config: GeneralizeConfig, rng: random.Random):
        self.b = behaviour
        self.pid = behaviour.participant_id
        self.g = Grounder(behaviour, registry)
        self.config = config
        self.rng = rng
        # (family, object name) -> count, and per-family totals, from annotated verbs
        self.done: dict[str, Counter] = {f: Counter() for f in FAMILIES}
        self.stirred: Counter = Counter()
        self.video_sets: dict[tuple[str, str], set[str]] = {}
        for video, steps in behaviour.steps_by_video.items():
            for s in steps:
                head, name = _head(s.verb), noun_text(s.action.noun)
                for family, (verbs, _) in FAMILIES.items():
                    if head in verbs or s.verb in verbs:
                        self.done[family][name] += 1
                        self.video_sets.setdefault((family, name), set()).add(video)
                if head in STIRRING or s.verb in STIRRING:
                    self.stirred[name] += 1
                    self.video_sets.setdefault(("stirring", name), set()).add(video)
        self.handled = Counter({noun_text(n): ev.count for n, ev in behaviour.noun_evidence.items()})
        self.video = max(behaviour.videos, key=lambda v: (len(behaviour.steps_by_video[v]), v))

    def _task(self, **kw) -> GeneralizeTask:
        return GeneralizeTask(video_id=self.video, participant_id=self.pid, **kw)

    def transfer(self) -> list[GeneralizeTask]:
        out = []
        families = sorted(FAMILIES, key=lambda f: (-sum(self.done[f].values()), f))
        for family in families:
            if len(out) >= self.config.max_transfer:
                break
            counts = self.done[family]
            total = sum(counts.values())
            if total < self.config.min_action_count:
                continue
            plausible = FAMILIES[family][1]
            sources = {n: c for n, c in counts.items() if n in plausible} or {
                n: c for n, c in counts.items() if n not in ("hand", "tap", "water")}
            if not sources:
                continue
            source, source_n = max(sources.items(), key=lambda kv: (kv[1], kv[0]))
            targets = [n for n, _ in sorted(self.handled.items(), key=lambda kv: (-kv[1], kv[0]))
                       if n in plausible and counts.get(n, 0) == 0]
            pool = targets[: self.config.targets_per_action * 2]
            self.rng.shuffle(pool)
            for target in sorted(pool[: self.config.targets_per_action], key=targets.index):
                if len(out) >= self.config.max_transfer:
                    break
                gerund = family
                out.append(self._task(
                    task_id=f"generalize_transfer_{self.pid}_{gerund}_{_slug(target)}", task_type="transfer",
                    task_query=_transfer_query(self.pid, family, target), source_action=gerund,
                    source_object=source, target_object=target,
                    ground_truth_steps=_transfer_steps(self.g, family, target),
                    rationale=(f"Person knows how to '{gerund}' the '{source}' ({source_n}x observed). "
                               f"Transfer to '{target}' (never observed with '{gerund}')."),
                    audit={"family_count": total, "source_count": source_n,
                           "source_videos": sorted(self.video_sets.get((family, source), set())),
                           "target_handled_count": self.handled[target], "target_count_with_action": 0},
                ))
        return out

    def _never_together(self, families: list[str], obj: str) -> bool:
        sets = [self.video_sets.get((f, obj), set()) for f in families]
        return not set.intersection(*sets) if sets else True

    def composition(self) -> list[GeneralizeTask]:
        out = []
        cut, peel, rinse, scrub = (sum(self.done[f].values()) for f in ("cutting", "peeling", "rinsing", "scrubbing"))
        stir = sum(self.stirred.values())
        veg = [n for n, _ in sorted(self.handled.items(), key=lambda kv: (-kv[1], kv[0])) if n in VEGETABLES]
        # 1. peel + cut + stir-fry a vegetable
        used = set()
        peelable = [v for v in veg if v in PEELABLE and self._never_together(["peeling", "cutting", "stirring"], v)]
        if peel >= 2 and cut >= 2 and stir >= 2 and peelable:
            v = peelable[0]
            used.add(v)
            steps = _steps_peeling(self.g, v)[:4] + _steps_cutting(self.g, v)[2:3] + [
                f"Cut the peeled {v} into small pieces on the {self.g.describe(self.g.fixture('board'))}."] + _steps_cook(self.g, v)
            out.append(self._task(
                task_id=f"generalize_composition_{self.pid}_prepare_and_cook_{_slug(v)}", task_type="composition",
                task_query=f"Help {self.pid} peel, chop, and stir-fry the {v}.",
                components=[f"peeling {v}", f"cutting {v}", f"stirring {v} in pan"], ground_truth_steps=steps,
                rationale=(f"Person knows: peeling ({peel}x), cutting ({cut}x), stirring ({stir}x). "
                           f"Composition: apply peel+cut+stir to {v}."),
                audit={"peeling": peel, "cutting": cut, "stirring": stir, "never_together_on": v},
            ))
        # 2. the full wash-dry-store cycle for dishes
        dishes_washed = sum(n for o, n in self.done["scrubbing"].items() if o in DISHES)
        dishes_rinsed = sum(n for o, n in self.done["rinsing"].items() if o in DISHES)
        cycle_videos = [
            v for v, steps in self.b.steps_by_video.items()
            if {"scrubbing", "rinsing", "drying"} <= {
                f for s in steps if noun_text(s.action.noun) in DISHES
                for f, heads in (("scrubbing", FAMILIES["scrubbing"][0]), ("rinsing", FAMILIES["rinsing"][0]),
                                 ("drying", frozenset({"dry"})))
                if _head(s.verb) in heads
            }
        ]
        if dishes_washed >= 2 and dishes_rinsed >= 2 and not cycle_videos:
            sink, tap, sponge, rack = (self.g.describe(self.g.fixture(k)) for k in ("sink", "tap", "sponge", "rack"))
            plate, bowl = self.g.describe(self.g.fixture("plate")), self.g.describe(self.g.fixture("bowl"))
            out.append(self._task(
                task_id=f"generalize_composition_{self.pid}_full_dishwashing_cycle", task_type="composition",
                task_query=f"Help {self.pid} wash all the dirty dishes, dry them, and put them away.",
                components=["scrubbing dishes", "rinsing dishes", "drying", "storing"],
                ground_truth_steps=[
                    f"Collect dirty dishes from the counter to the {sink}.", f"Turn on the {tap}.",
                    f"Apply dish soap to the {sponge}.", f"Scrub the {plate} with the {sponge}.",
                    f"Rinse the {plate} under running water.", f"Place the clean {plate} on the {rack}.",
                    f"Scrub the {bowl} with the {sponge}.", f"Rinse the {bowl} under running water.",
                    f"Place the clean {bowl} on the {rack}.", f"Turn off the {tap}.",
                    f"Dry the dishes with the {self.g.describe(self.g.fixture('cloth'))}.",
                    f"Put the dry dishes away in the {self.g.describe(self.g.fixture('cupboard'))}.",
                ],
                rationale=(f"Person knows: scrubbing dishes ({dishes_washed}x), rinsing dishes ({dishes_rinsed}x); "
                           "never observed washing, rinsing and drying in one session. Composition: extend to the "
                           "full wash-dry-store cycle."),
                audit={"dishes_scrubbed": dishes_washed, "dishes_rinsed": dishes_rinsed, "full_cycle_videos": []},
            ))
        # 3. wash + cut + stir-fry a vegetable
        washable = [v for v in veg if v not in used and self._never_together(["rinsing", "cutting", "stirring"], v)]
        if (rinse + scrub) >= 2 and cut >= 2 and stir >= 2 and washable:
            v = washable[0]
            steps = _steps_rinsing_produce(self.g, v)[:5] + [
                f"Place the rinsed {v} on the {self.g.describe(self.g.fixture('board'))}."] + _steps_cutting(self.g, v)[2:3] + [
                f"Cut the {v} into bite-sized pieces on the {self.g.describe(self.g.fixture('board'))}."] + _steps_cook(self.g, v)
            out.append(self._task(
                task_id=f"generalize_composition_{self.pid}_prep_cook_{_slug(v)}", task_type="composition",
                task_query=f"Help {self.pid} wash, cut, and stir-fry the {v}.",
                components=[f"washing {v}", f"cutting {v}", "stir-frying"], ground_truth_steps=steps,
                rationale=(f"Person knows: rinsing ({rinse}x), cutting ({cut}x), stirring ({stir}x). "
                           f"Composition: wash+cut+cook applied to {v}."),
                audit={"rinsing": rinse, "cutting": cut, "stirring": stir, "never_together_on": v},
            ))
        return out

    def novel(self) -> list[GeneralizeTask]:
        g = self.g
        plate, bowl, knife, fork, cup = (g.describe(g.fixture(k)) for k in ("plate", "bowl", "knife", "fork", "cup"))
        cloth, tap, sink, board = (g.describe(g.fixture(k)) for k in ("cloth", "tap", "sink", "board"))
        place = lambda k, key: g.place(g.fixture(k), key)  # noqa: E731
        veg = "cucumber"
        return [
            self._task(
                task_id=f"generalize_novel_{self.pid}_set_table_for_meal", task_type="fully_novel",
                task_query=f"Help {self.pid} set the table for a meal with plate, bowl, and cutlery.",
                ground_truth_steps=[
                    f"Pick up the {plate} from the {place('plate', 'plate')}.", f"Place the {plate} on the table.",
                    f"Pick up the {bowl} from the {place('bowl', 'bowl')}.", f"Place the {bowl} above the plate on the table.",
                    f"Pick up the {knife} from the {place('knife', 'knife')}.", "Place the knife to the right of the plate on the table.",
                    f"Pick up the {fork} from the {place('fork', 'fork')}.", "Place the fork to the left of the plate on the table.",
                    f"Pick up the {cup} from the {place('cup', 'cup')}.", "Place the cup above the knife on the table.",
                ],
                rationale="Person never observed setting a table, but the locations of plates, bowls and cutlery are known from their kitchen activity.",
            ),
            self._task(
                task_id=f"generalize_novel_{self.pid}_clean_kitchen_countertop", task_type="fully_novel",
                task_query=f"Help {self.pid} clear and clean the entire kitchen countertop.",
                ground_truth_steps=[
                    f"Clear loose items from the countertop to the {sink}.", f"Pick up the {cloth} from the {place('cloth', 'cloth')}.",
                    f"Turn on the {tap}.", f"Wet the {cloth} under the {tap}.", f"Turn off the {tap}.",
                    f"Wipe the countertop surface from one end to the other with the {cloth}.",
                    f"Rinse the {cloth} under the {tap}.", "Wipe the countertop again to remove residue.",
                    f"Rinse and wring out the {cloth}.", f"Place the {cloth} back on the {place('cloth', 'cloth')}.",
                ],
                rationale="Person wipes surfaces but was never observed cleaning the whole countertop; requires generalizing wiping patterns.",
            ),
            self._task(
                task_id=f"generalize_novel_{self.pid}_prepare_simple_salad", task_type="fully_novel",
                task_query=f"Help {self.pid} prepare a simple salad using available vegetables.",
                ground_truth_steps=[
                    f"Pick up the {g.describe(veg)} from the {g.place(veg, g.key_for(veg))}.", f"Turn on the {tap}.",
                    f"Rinse the {veg} under running water in the {sink}.", f"Turn off the {tap}.",
                    f"Place the {veg} on the {board}.", f"Pick up the {knife} from the {place('knife', 'knife')}.",
                    f"Cut the {veg} into slices on the {board}.", f"Transfer the {veg} slices to the {bowl}.",
                    f"Place the {knife} back on the {place('knife', 'knife')}.", f"Mix the salad ingredients in the {bowl}.",
                ],
                rationale="Person has cutting and vegetable-handling experience, but salad preparation (raw assembly) is a novel task category.",
            ),
        ]


def generate_generalize(behaviour: Behaviour, registry: list[dict] | None = None,
                        config: GeneralizeConfig | None = None) -> list[GeneralizeTask]:
    config = config or GeneralizeConfig()
    rng = random.Random(f"{config.seed}:{behaviour.participant_id}:generalize")
    builder = GeneralizeBuilder(behaviour, registry, config, rng)
    return builder.transfer() + builder.composition() + builder.novel()

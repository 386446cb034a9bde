"""A participant's observed behaviour, indexed from EPIC action annotations for task generation.

The generators read only this index (never pixels, never a memory bank): per-video action
streams, consecutive identical actions collapsed into runs, and the statistics the paper's
construction step (i) names: verb/noun marginals, verb-object pairs, trigger->next tables,
action chains, and where objects are put or taken from. Phrasing helpers turn actions into
the English used by questions and choices.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import polars as pl

from memora_graph.perceive.annotations import load_class_tables
from memora_graph.paths import epic_dir

# Verb classes that move or expose things without doing anything characteristic. Chains made
# only of these are the "universal flows" (pick-up -> put-down, open -> close) the paper rejects.
FILLER_VERB_KEYS = frozenset({
    "take", "put", "open", "close", "move", "hold", "insert", "remove", "lift", "pull", "look",
    "search", "feel", "wait", "let-go", "carry", "choose", "transition", "use", "finish", "gather",
    "check", "turn", "press", "touch", "drop", "slide", "attach", "set", "unlock", "lock",
})
HAND_VERB_KEYS = frozenset({"wash", "dry", "shake", "wipe", "rub"})
PUT_VERB_KEYS = frozenset({"put", "insert", "throw", "drop"})
TAKE_VERB_KEYS = frozenset({"take", "remove"})
# Verbs whose second noun is usually the instrument ("wash plate with sponge", "cut onion with
# knife"); pour/put-like verbs are excluded because their second noun is a destination.
TOOL_VERB_KEYS = frozenset({
    "wash", "cut", "wipe", "mix", "stir", "scoop", "dry", "scrub", "peel", "spread", "scrape",
    "rub", "brush", "grate", "crush",
})
TOOL_CATEGORIES = frozenset({"cutlery", "utensils", "cleaning equipment and material", "materials"})
PLACE_CATEGORIES = frozenset({
    "furniture", "storage", "appliances", "containers", "cookware", "crockery", "rubbish", "utensils",
})
MAX_SEQUENCE = 4  # longest run sequence a generator asks about (trigger + 3 steps)
_PREPOSITIONS = ("into", "onto", "in", "on", "under", "over", "inside", "back", "from", "to", "off")
_CONTAINER_WORDS = frozenset({
    "sink", "drawer", "fridge", "freezer", "cupboard", "bin", "bowl", "pan", "pot", "bag", "box",
    "container", "jar", "basket", "dishwasher", "microwave", "oven", "kettle", "cup", "glass", "jug",
    "colander", "rubbish",
})


class ActionClass(NamedTuple):
    """One verb class acting on one noun class, e.g. ActionClass('wash', 'plate')."""

    verb: str
    noun: str

    @property
    def is_filler(self) -> bool:
        return self.verb in FILLER_VERB_KEYS

    @property
    def phrasable(self) -> bool:
        """False for label combinations that read as nonsense in English ('eats their hands')."""
        return self.noun != "hand" or self.verb in HAND_VERB_KEYS

    def key(self) -> str:
        return f"{self.verb} {self.noun}"


@dataclass(frozen=True)
class ActionRow:
    """One annotated EPIC action row."""

    narration_id: str
    video_id: str
    start_s: float
    stop_s: float
    narration: str
    verb: str  # as annotated, e.g. 'pour-into'
    noun: str  # as annotated, e.g. 'bottle:milk'
    action: ActionClass  # class keys
    place: str  # second noun class key for put/take-like rows ('' when none)
    tool: str  # second noun class key for tool-using rows ('' when none)
    text_source: str


@dataclass(frozen=True)
class Run:
    """Consecutive steps of one video with the same action, collapsed into one event."""

    action: ActionClass
    steps: tuple[ActionRow, ...]

    @property
    def video_id(self) -> str:
        return self.steps[0].video_id

    @property
    def start_s(self) -> float:
        return self.steps[0].start_s


@dataclass
class Evidence:
    """Where a fact was observed: (video_id, start second, narration_id) triples."""

    hits: list[tuple[str, float, str]] = field(default_factory=list)

    def add(self, step: ActionRow) -> None:
        self.hits.append((step.video_id, step.start_s, step.narration_id))

    @property
    def count(self) -> int:
        return len(self.hits)

    @property
    def videos(self) -> list[str]:
        return sorted({v for v, _, _ in self.hits})

    def audit(self, limit: int = 8) -> dict:
        hits = sorted(self.hits)
        return {
            "count": self.count,
            "videos": self.videos,
            "timestamps": [{"video_id": v, "time": clock(t), "narration_id": n} for v, t, n in hits[:limit]],
        }


def clock(seconds: float) -> str:
    """Seconds as the release's HH:MM:SS.ss."""
    cs = int(round(seconds * 100))
    h, rem = divmod(cs, 360000)
    m, rem = divmod(rem, 6000)
    s, c = divmod(rem, 100)
    return f"{h:02d}:{m:02d}:{s:02d}.{c:02d}"


class Behaviour:
    """The index of one participant's annotated actions."""

    def __init__(self, participant_id: str, steps_by_video: dict[str, list[ActionRow]], noun_category: dict[str, str]):
        self.participant_id = participant_id
        self.steps_by_video = steps_by_video
        self.videos = sorted(steps_by_video)
        self.noun_category = noun_category
        self.runs_by_video = {v: _collapse(steps) for v, steps in steps_by_video.items()}
        self._seq_cache: dict[str, set[tuple[ActionClass, ...]]] = {}
        self._all_sequences: set[tuple[ActionClass, ...]] | None = None
        self._index()

    # -- statistics -------------------------------------------------------------------------
    def _index(self) -> None:
        self.action_evidence: dict[ActionClass, Evidence] = defaultdict(Evidence)
        self.video_action_counts: dict[str, Counter] = {}
        self.chain_next: dict[tuple[ActionClass, ...], dict[ActionClass, Evidence]] = defaultdict(lambda: defaultdict(Evidence))
        self.places: dict[tuple[str, str], dict[str, Evidence]] = defaultdict(lambda: defaultdict(Evidence))
        self.tools: dict[ActionClass, dict[str, Evidence]] = defaultdict(lambda: defaultdict(Evidence))
        self.noun_evidence: dict[str, Evidence] = defaultdict(Evidence)
        for video in self.videos:
            runs = self.runs_by_video[video]
            counts = Counter()
            for i, run in enumerate(runs):
                counts[run.action] += 1
                self.action_evidence[run.action].add(run.steps[0])
                for k in (1, 2, 3):
                    if i - k + 1 >= 0 and i + 1 < len(runs):
                        chain = tuple(r.action for r in runs[i - k + 1:i + 1])
                        self.chain_next[chain][runs[i + 1].action].add(runs[i + 1].steps[0])
            for step in self.steps_by_video[video]:
                self.noun_evidence[step.action.noun].add(step)
                if step.place:
                    kind = "put" if step.action.verb in PUT_VERB_KEYS else "take"
                    self.places[(kind, step.action.noun)][step.place].add(step)
                if step.tool:
                    self.tools[step.action][step.tool].add(step)
            self.video_action_counts[video] = counts

    def chains(self, video: str, length: int) -> list[tuple[Run, ...]]:
        runs = self.runs_by_video[video]
        return [tuple(runs[i:i + length]) for i in range(len(runs) - length + 1)]

    def _sequences(self, video: str) -> set[tuple[ActionClass, ...]]:
        if video not in self._seq_cache:
            actions = [r.action for r in self.runs_by_video[video]]
            self._seq_cache[video] = {
                tuple(actions[i:i + n]) for n in range(1, MAX_SEQUENCE + 1) for i in range(len(actions) - n + 1)
            }
        return self._seq_cache[video]

    def occurs_in_video(self, video: str, actions: tuple[ActionClass, ...]) -> bool:
        """True when the actions occur as consecutive runs somewhere in the video."""
        if len(actions) > MAX_SEQUENCE:
            raise ValueError(f"sequences longer than {MAX_SEQUENCE} are not indexed")
        return tuple(actions) in self._sequences(video)

    def occurs_anywhere(self, actions: tuple[ActionClass, ...]) -> bool:
        if self._all_sequences is None:
            self._all_sequences = set().union(*(self._sequences(v) for v in self.videos))
        if len(actions) > MAX_SEQUENCE:
            raise ValueError(f"sequences longer than {MAX_SEQUENCE} are not indexed")
        return tuple(actions) in self._all_sequences

    def facts(self) -> set[str]:
        """Keys of everything observed, used to check that a donor question finds no support here."""
        out = {f"action:{a.key()}" for a in self.action_evidence}
        for chain, nexts in self.chain_next.items():
            for nxt in nexts:
                out.add("chain:" + " > ".join(a.key() for a in (*chain, nxt)))
        for (kind, noun), places in self.places.items():
            out.update(f"{kind}:{noun}@{p}" for p in places)
        for action, tools in self.tools.items():
            out.update(f"tool:{action.key()}@{t}" for t in tools)
        return out

    def category(self, noun: str) -> str:
        return self.noun_category.get(noun, "other")


def _collapse(steps: list[ActionRow]) -> list[Run]:
    runs: list[Run] = []
    for step in steps:
        if runs and runs[-1].action == step.action:
            runs[-1] = Run(step.action, runs[-1].steps + (step,))
        else:
            runs.append(Run(step.action, (step,)))
    return runs


def _second_noun(row: dict, noun_key: dict[int, str], noun_category: dict[str, str], wanted: frozenset) -> str:
    """The first other noun of the row whose category fits (a place for put/take, a tool otherwise)."""
    main = noun_key.get(int(row["noun_class"]), "")
    for cls in (row["all_noun_classes"] or [])[1:]:
        key = noun_key.get(int(cls), "")
        if key and key != main and noun_category.get(key, "other") in wanted:
            return key
    return ""


def build_behaviours(annotations: pl.DataFrame, class_dir: str | Path | None = None) -> dict[str, Behaviour]:
    """Index every participant of an annotation frame (from `load_annotations`)."""
    tables = load_class_tables(Path(class_dir) if class_dir else epic_dir())
    noun_key = tables.nouns
    noun_category = {noun_key[i]: cat for i, cat in tables.noun_category.items()}
    by_pid: dict[str, dict[str, list[ActionRow]]] = defaultdict(lambda: defaultdict(list))
    for row in annotations.iter_rows(named=True):
        action = ActionClass(row["verb_key"], noun_key[int(row["noun_class"])])
        place = tool = ""
        if action.verb in PUT_VERB_KEYS or action.verb in TAKE_VERB_KEYS:
            place = _second_noun(row, noun_key, noun_category, PLACE_CATEGORIES)
        elif action.verb in TOOL_VERB_KEYS:
            tool = _second_noun(row, noun_key, noun_category, TOOL_CATEGORIES)
        by_pid[row["participant_id"]][row["video_id"]].append(ActionRow(
            narration_id=row["narration_id"], video_id=row["video_id"], start_s=float(row["start_s"]),
            stop_s=float(row["stop_s"]), narration=row["narration"], verb=row["verb"], noun=row["noun"],
            action=action, place=place, tool=tool, text_source=row["text_source"],
        ))
    out = {}
    for pid in sorted(by_pid):
        videos = {v: sorted(s, key=lambda x: (x.start_s, x.stop_s, x.narration_id)) for v, s in sorted(by_pid[pid].items())}
        out[pid] = Behaviour(pid, videos, noun_category)
    return out


# ---------------------------------------------------------------------------------------------
# Phrasing
# ---------------------------------------------------------------------------------------------

_NEEDS_PREPOSITION = {"look": "at", "search": "for", "wait": "for"}
_IRREGULAR_3RD = {"have": "has", "do": "does", "go": "goes"}
_GERUND = {"put": "putting", "cut": "cutting", "stir": "stirring", "scrub": "scrubbing", "pat": "patting",
           "flip": "flipping", "drop": "dropping", "wrap": "wrapping", "rip": "ripping", "stab": "stabbing",
           "unwrap": "unwrapping", "let-go": "letting go of", "set": "setting", "shake": "shaking"}


_PAST = {"take": "took", "put": "put", "cut": "cut", "throw": "threw", "eat": "ate", "drink": "drank", "hold": "held",
         "shake": "shook", "break": "broke", "set": "set", "spread": "spread", "let-go": "let go of", "stir": "stirred",
         "pat": "patted", "flip": "flipped", "drop": "dropped", "wrap": "wrapped", "rip": "ripped", "stab": "stabbed",
         "unwrap": "unwrapped", "scrub": "scrubbed", "grind": "ground", "hang": "hung", "wear": "wore", "rub": "rubbed",
         "chop": "chopped", "dry": "dried", "fry": "fried", "empty": "emptied", "carry": "carried", "apply": "applied"}


def past(verb: str) -> str:
    """'turn-on' -> 'turned on', 'take' -> 'took'."""
    head, *rest = verb.split("-")
    if verb in _PAST:
        return _PAST[verb]
    if head in _PAST:
        word = _PAST[head]
    elif head.endswith("e"):
        word = head + "d"
    elif head.endswith("y") and len(head) > 1 and head[-2] not in "aeiou":
        word = head[:-1] + "ied"
    else:
        word = head + "ed"
    return " ".join([word, *rest])


_PARTICIPLE = {"take": "taken", "eat": "eaten", "drink": "drunk", "throw": "thrown", "shake": "shaken",
               "break": "broken", "wear": "worn"}


def participle(verb: str) -> str:
    """'take' -> 'taken', 'turn-on' -> 'turned on'."""
    head, *rest = verb.split("-")
    return " ".join([_PARTICIPLE[head], *rest]) if head in _PARTICIPLE else past(verb)


def noun_text(noun: str) -> str:
    """EPIC 'head:modifier...' as English: 'board:chopping' -> 'chopping board',
    'liquid:washing:up' -> 'washing up liquid'."""
    parts = [p for p in noun.replace("_", " ").split(":") if p]
    return " ".join(parts[1:] + parts[:1]) if parts else noun


def _third_person(word: str) -> str:
    if word in _IRREGULAR_3RD:
        return _IRREGULAR_3RD[word]
    if word.endswith(("s", "sh", "ch", "x", "z", "o")):
        return word + "es"
    if word.endswith("y") and len(word) > 1 and word[-2] not in "aeiou":
        return word[:-1] + "ies"
    return word + "s"


def _gerund(word: str) -> str:
    if word in _GERUND:
        return _GERUND[word]
    if word.endswith("ie"):
        return word[:-2] + "ying"
    if word.endswith("e") and not word.endswith(("ee", "ye", "oe")):
        return word[:-1] + "ing"
    return word + "ing"


def verb_phrase(verb: str, form: str = "present") -> str:
    """'turn-on' -> 'turns on' (present) / 'turning on' (gerund) / 'turn on' (base)."""
    if verb == "let-go":
        return {"present": "lets go of", "gerund": "letting go of", "base": "let go of"}[form]
    head, *rest = verb.split("-")
    if not rest and head in _NEEDS_PREPOSITION:
        rest = [_NEEDS_PREPOSITION[head]]
    if form == "present":
        head = _third_person(head)
    elif form == "gerund":
        head = _GERUND.get(head) or _gerund(head)
    return " ".join([head, *rest])


def object_text(noun: str) -> str:
    """'the plate'; the hand class reads 'their hands'."""
    return "their hands" if noun == "hand" else f"the {noun_text(noun)}"


def action_phrase(action: ActionClass, form: str = "present", place: str = "", raw_verb: str = "") -> str:
    """'washes the plate'; with a place: 'puts the plate in the sink'; a bare put: 'puts down the plate'."""
    verb = verb_phrase(action.verb, form)
    if action.verb == "put" and not place:
        verb += " down"
    text = f"{verb} {object_text(action.noun)}"
    if place:
        text += f" {place_preposition(raw_verb, place)} the {noun_text(place)}"
    return text


def pronoun_phrase(verb: str) -> str:
    """'Washes it', 'Turns it on' (the particle goes after the pronoun)."""
    head, *rest = verb_phrase(verb).split(" ")
    return " ".join([head[:1].upper() + head[1:], "it", *rest])


def place_preposition(raw_verb: str, place: str, taking: bool = False) -> str:
    if taking:
        return "from"
    suffix = raw_verb.split("-")[-1] if "-" in raw_verb else ""
    if suffix in _PREPOSITIONS and suffix not in ("back", "from", "off"):
        return suffix
    return "in" if place.split(":")[0] in _CONTAINER_WORDS else "on"


def sequence_phrase(actions: list[ActionClass] | tuple[ActionClass, ...]) -> str:
    """'rinses the pan, then scrubs the pan, then puts the pan down' style (capitalised)."""
    parts = [action_phrase(a) for a in actions]
    text = ", then ".join(parts)
    return text[0].upper() + text[1:]

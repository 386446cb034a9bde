"""The planning metrics' vocabulary (docs/evaluation.md): action verbs, location nouns and
prepositions of the Exec predicates, and the verb normalization OrderExec compares plans by."""

from __future__ import annotations

import re

from memora_graph.text import stem

ACTION_VERBS = (
    "pick up", "put down", "open", "close", "wash", "pour", "cut", "turn on", "turn off", "place", "move", "take",
    "grab", "rinse", "dry", "wipe", "slice", "chop", "peel", "stir", "mix", "squeeze", "fill", "empty", "flip",
    "scoop", "spread", "throw", "shake", "scrub", "adjust", "pull", "push", "set", "remove", "add", "press", "lift",
    "lower", "fold", "unfold", "heat", "boil", "fry", "bake", "toast", "grate", "crack", "whisk", "measure",
    "transfer", "serve", "bring", "carry", "reach", "reach for", "grasp", "hold", "grip", "release", "position",
    "continue", "approach", "locate", "identify", "prepare", "ensure", "gather", "collect", "arrange", "toss",
    "dispose", "discard", "rotate", "check", "inspect", "retrieve", "return", "stack", "pick_up", "reach_for",
    "picks up", "places", "holding", "scrubbing", "rinsing", "wiping", "peeling", "stirring", "cutting",
)
LOCATION_NOUNS = (
    "counter", "countertop", "cabinet", "sink", "shelf", "drawer", "fridge", "refrigerator", "stove", "oven",
    "table", "rack", "drying rack", "dish rack", "worktop", "pan", "pot", "board", "cutting board",
    "chopping board", "microwave", "dishwasher", "bin", "trash", "garbage", "hob", "burner", "plate rack",
    "sink area", "sink_area", "counter area", "countertop_area", "left zone", "right zone", "center zone",
    "table_area", "drying_rack_area", "left_zone", "right_zone", "center_zone", "colander", "bowl", "plate", "tap",
    "faucet",
)
LOCATION_PREPOSITIONS = (
    "on", "in", "from", "near", "next to", "under", "above", "inside", "at", "behind", "beside", "between", "onto",
    "into", "out of", "toward", "towards", "across",
)
OBJECT_STOPWORDS = frozenset({"the", "a", "an", "and", "or", "then", "to", "with", "for", "is", "are"})
PRONOUN_ONLY = frozenset({"it", "the thing", "that", "this", "them", "those", "these", "something", "stuff"})


FILLER = "_filler_"
_BASE_SYNONYMS = {
    "grab": "grasp", "hold": "grasp", "grip": "grasp", "pick up": "grasp", "take": "grasp", "get": "grasp",
    "put": "place", "set": "place", "lay": "place", "rest": "place", "drop": "place", "position": "place",
    "carry": "move", "bring": "move", "transfer": "move", "transport": "move",
    "twist": "turn", "rotate": "turn", "switch": "turn", "turn on": "turn", "turn off": "turn",
    "wash": "wash", "clean": "wash", "scrub": "wash", "rinse": "rinse",
    "cut": "cut", "slice": "cut", "chop": "cut", "dice": "cut",
    "pour": "pour", "drizzle": "pour", "add": "pour", "open": "open", "close": "close", "shut": "close",
    "stir": "stir", "mix": "stir", "whisk": "stir", "peel": "peel", "reach": "reach", "extend": "reach",
    "wipe": "wipe", "fill": "fill", "refill": "fill", "the person is": "",
}
_INFLECTIONS = {
    "grasp": "grasping grasps grasped picking picks picked grabbing grabs grabbed taking takes took taken "
             "holding holds held getting gets got",
    "place": "placing places placed putting puts setting sets laying lays laid dropping drops dropped "
             "positioning positions positioned",
    "move": "moving moves moved carrying carries carried bringing brings brought transferring transfers transferred",
    "turn": "turning turns turned twisting twists twisted rotating rotates rotated switching switches switched",
    "wash": "washing washes washed cleaning cleans cleaned scrubbing scrubs scrubbed",
    # unlike the reference implementation, every rinse form stays "rinse" ("rinses X" is not "wash")
    "rinse": "rinsing rinses rinsed",
    "cut": "cutting cuts slicing slices sliced chopping chops chopped dicing dices diced",
    "pour": "pouring pours poured drizzling drizzles drizzled adding adds added",
    "open": "opening opens opened", "close": "closing closes closed shutting shuts",
    "stir": "stirring stirs stirred mixing mixes mixed whisking whisks whisked",
    "peel": "peeling peels peeled", "reach": "reaching reaches reached extending extends extended",
    "wipe": "wiping wipes wiped", "fill": "filling fills filled refilling refills refilled",
    "prepare": "preparing prepares prepared", "cook": "cooking cooks cooked", "use": "using uses used",
    "begin": "beginning begins began starting starts started", "continue": "continuing continues continued",
    "knead": "kneading kneads kneaded", "fold": "folding folds folded", "press": "pressing presses pressed",
    "shake": "shaking shakes shook shaken", "squeeze": "squeezing squeezes squeezed",
    "drain": "draining drains drained", "boil": "boiling boils boiled", "fry": "frying fries fried",
}
VERB_SYNONYMS: dict[str, str] = dict(_BASE_SYNONYMS)
for _canon, _forms in _INFLECTIONS.items():
    VERB_SYNONYMS.setdefault(_canon, _canon)
    for _form in _forms.split():
        VERB_SYNONYMS.setdefault(_form, _canon)
for _canon in set(v for v in _BASE_SYNONYMS.values() if v):
    VERB_SYNONYMS.setdefault(_canon, _canon)
_SYNONYM_KEYS = sorted(VERB_SYNONYMS, key=lambda k: (-len(k), k))
_SUBJECT_WORDS = frozenset({"person", "a", "the", "he", "she", "they", "it", "user", "participant", "subject"})
_PERSON_PREFIX = re.compile(r"^(?:(?:the|a)\s+)?person(?:\s+|$)(?:(?:is|are|was|were|will|begins?(?:\s+to)?|continues?(?:\s+to)?)(?:\s+|$))?")
_PRONOUN_PREFIX = re.compile(r"^(?:he|she|they|it)(?:\s+|$)(?:(?:is|are|was|were|will|then)(?:\s+|$))?")


def extract_action_verb(text: str) -> str:
    """The normalized action verb of a step ("_filler_" when it has none)."""
    t = text.lower().strip()
    t = re.sub(r"^\s*\d+\s*[.)]\s*", "", t)
    t = _PERSON_PREFIX.sub("", t)
    t = _PRONOUN_PREFIX.sub("", t).strip()
    for key in _SYNONYM_KEYS:
        if t == key or t.startswith(key + " ") or (
            key.endswith(("s", "h", "x")) and (t.startswith(key + "es ") or t.startswith(key + "s "))
        ):
            return VERB_SYNONYMS[key] or FILLER
    words = re.findall(r"[a-z_]+", t)
    if not words:
        return FILLER
    head = words[0]
    if head in _SUBJECT_WORDS:
        if len(words) < 2 or words[1] in _SUBJECT_WORDS:
            return FILLER
        head = words[1]
    stemmed = stem(head)
    return VERB_SYNONYMS.get(head) or VERB_SYNONYMS.get(stemmed) or stemmed

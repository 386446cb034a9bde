"""Word lists of the deterministic consolidation policy (EPIC verb class keys, noun categories).

The verb categories follow the reference implementation (cleanup / cooking / prep / setup / filler);
they decide what an episode is about and which steps are bookkeeping (take, put, open, ...)
rather than the work itself.
"""

from __future__ import annotations

from memora_graph.perceive.vocab import VERB_STATE

CLEANUP = frozenset({"wash", "rinse", "clean", "wipe", "dry", "sponge", "scrub", "rub", "soak", "brush", "spray"})
COOKING = frozenset({
    "fry", "boil", "cook", "bake", "roast", "simmer", "heat", "stir", "mix", "flip", "pour", "season",
    "add", "fold", "stretch", "roll", "form", "knead", "spread", "apply", "coat", "fill", "flatten",
})
PREP = frozenset({"cut", "chop", "peel", "slice", "grate", "crush", "mash", "break", "divide", "stab", "rip", "squeeze", "filter"})
SETUP = frozenset({
    "turn-on", "turn-off", "switch", "adjust", "check", "shake", "scoop", "sprinkle", "empty", "press",
    "measure", "look", "search", "turn-down", "wear", "attach", "lock", "unlock", "scrape", "pat", "sort", "mark",
})
FILLER = frozenset({
    "take", "put", "open", "close", "insert", "move", "remove", "hold", "lift", "let-go", "carry", "gather",
    "choose", "set", "hang", "drop", "pull", "turn", "slide", "unroll", "uncover", "wrap", "unwrap",
    "throw", "transition", "screw", "unscrew",
})
RELEASING = frozenset({"put", "insert", "hang", "drop", "let-go", "set", "slide"})
TAKING = frozenset({"take", "remove", "lift", "gather", "choose", "carry"})

CATEGORY_OF_VERB = {v: c for c, vs in (("cleanup", CLEANUP), ("cooking", COOKING), ("prep", PREP), ("setup", SETUP))
                    for v in vs}

# Routine activity types (the reference implementation's typing of routines).
ACTIVITY_TYPE = {
    "cleanup": "cleanup_organization", "cooking": "multi_step_cooking", "prep": "meal_preparation",
    "setup": "object_retrieval_setup", None: "routine_reproduction",
}

# Readable verb forms for statements ("after washing the bowl ..."). Others get a rule.
GERUND = {
    "put": "putting", "cut": "cutting", "let-go": "letting go of", "turn-on": "turning on",
    "turn-off": "turning off", "turn-down": "turning down", "stab": "stabbing", "rip": "ripping",
    "drop": "dropping", "pat": "patting", "scrub": "scrubbing", "set": "setting", "shake": "shaking",
}
PHRASE = {"turn-on": "turn on", "turn-off": "turn off", "turn-down": "turn down", "let-go": "let go of", "mix": "mix"}
# Extra keywords a verb answers to, so "stir the eggs" finds a preference recorded as "mix egg".
SYNONYMS = {
    "mix": ("stir", "whisk"), "wash": ("clean", "rinse"), "cut": ("slice", "chop"), "take": ("pick", "grab"),
    "put": ("place",), "scoop": ("spoon",), "apply": ("spread",), "insert": ("put", "place"),
    "scrape": ("scrape",), "dry": ("wipe",),
}

# Objects that are instruments: a narration "stir egg in pan using spatula" names one as the tool.
TOOL_CATEGORIES = frozenset({"cutlery", "utensils", "cleaning equipment and material"})
# Where things are kept (storage context), as zones (fixture kinds) and place ids.
STORAGE_ZONES = frozenset({"cupboard", "drawer", "shelf", "fridge", "freezer", "cabinet", "pantry", "rack"})
STORAGE_KINDS = frozenset({"cupboard", "drawer", "shelf", "fridge", "freezer", "cabinet", "drying_rack", "rack",
                           "dishwasher", "cutlery_tray", "container", "box"})
STORAGE_PLACES = frozenset({"cabinet_area", "fridge_area"})


def phrase(verb: str) -> str:
    return PHRASE.get(verb, verb.replace("-", " "))


def past_tense(verb: str) -> str:
    """The participle a statement uses ("washed", "cut"): the verb's resulting state when it is one."""
    state = VERB_STATE.get(verb, "")
    if state and state.endswith("ed") or state in ("cut", "broken", "torn", "shaken"):
        return state
    return phrase(verb) + ("d" if verb.endswith("e") else "ed")


def gerund(verb: str) -> str:
    if verb in GERUND:
        return GERUND[verb]
    base = verb.replace("-", " ").split()[0]
    rest = verb.replace("-", " ")[len(base):]
    if base.endswith("ie"):
        g = base[:-2] + "ying"
    elif base.endswith("e") and not base.endswith(("ee", "ye", "oe")):
        g = base[:-1] + "ing"
    else:
        g = base + "ing"
    return g + rest


def third_person(verb: str) -> str:
    base = verb.replace("-", " ").split()[0]
    rest = verb.replace("-", " ")[len(base):]
    if base.endswith(("s", "sh", "ch", "x", "z")):
        t = base + "es"
    elif base.endswith("y") and base[-2:-1] not in "aeiou":
        t = base[:-1] + "ies"
    else:
        t = base + "s"
    return t + rest


def category(verb: str) -> str | None:
    return CATEGORY_OF_VERB.get(verb)

"""Word lists that turn EPIC verb/noun class keys into places, states and attributes.

These are the rules of the CPU perception path. Location ids follow the reference implementation's
(sink/dishwasher/stove/fridge/counter/table/cabinet `_area`, default `kitchen_general`); we add
`bin_area` because EPIC narrates throwing things away often enough to matter.
"""

from __future__ import annotations

DEFAULT_PLACE = "kitchen_general"

# noun class key -> (location id, zone name). These nouns are places as well as (fixed) objects.
PLACE_NOUNS: dict[str, tuple[str, str]] = {
    "sink": ("sink_area", "sink"),
    "tap": ("sink_area", "tap"),
    "rack:drying": ("sink_area", "drying rack"),
    "dishwasher": ("dishwasher_area", "dishwasher"),
    "machine:washing": ("dishwasher_area", "washing machine"),
    "hob": ("stove_area", "hob"),
    "oven": ("stove_area", "oven"),
    "cooker:slow": ("stove_area", "slow cooker"),
    "fan:extractor": ("stove_area", "extractor fan"),
    "microwave": ("stove_area", "microwave"),
    "fridge": ("fridge_area", "fridge"),
    "freezer": ("fridge_area", "freezer"),
    "top": ("counter_area", "worktop"),
    "kitchen": ("counter_area", "worktop"),
    "cupboard": ("cabinet_area", "cupboard"),
    "drawer": ("cabinet_area", "drawer"),
    "shelf": ("cabinet_area", "shelf"),
    "chair": ("table_area", "chair"),
    "bin": ("bin_area", "bin"),
    "floor": (DEFAULT_PLACE, "floor"),
    "wall": (DEFAULT_PLACE, "wall"),
    "window": (DEFAULT_PLACE, "window"),
    "door:kitchen": (DEFAULT_PLACE, "kitchen door"),
}

PLACE_NAMES = {
    "sink_area": "sink area", "dishwasher_area": "dishwasher area", "stove_area": "stove area",
    "fridge_area": "fridge area", "counter_area": "counter area", "cabinet_area": "cabinet area",
    "table_area": "table area", "bin_area": "bin area", DEFAULT_PLACE: "kitchen",
}

# Verbs whose place is implied when the narration names none (an affordance prior).
VERB_PLACE: dict[str, str] = {
    "wash": "sink_area", "dry": "sink_area", "scrub": "sink_area", "soak": "sink_area",
    "rub": "sink_area", "cut": "counter_area", "peel": "counter_area", "grate": "counter_area",
    "crush": "counter_area", "divide": "counter_area", "knead": "counter_area",
    "roll": "counter_area", "flatten": "counter_area", "cook": "stove_area",
    "bake": "stove_area", "turn-down": "stove_area",
}

# Not objects a memory should track.
NON_OBJECTS = {"hand", "face", "air", "heat", "power", "light", "alarm", "recipe", "watch", "kitchen"}

# verb class key -> the state an object is left in.
VERB_STATE: dict[str, str] = {
    "take": "held", "lift": "held", "hold": "held", "carry": "held", "gather": "held",
    "choose": "held", "scoop": "scooped", "remove": "removed", "put": "placed",
    "insert": "inserted", "hang": "placed", "drop": "placed", "let-go": "placed",
    "serve": "served", "set": "placed", "wash": "washed", "scrub": "washed", "rub": "washed",
    "brush": "washed", "soak": "soaking", "scrape": "scraped", "dry": "dried", "open": "open",
    "unroll": "open", "uncover": "open", "unwrap": "unwrapped", "unscrew": "open",
    "unlock": "open", "close": "closed", "wrap": "wrapped", "lock": "closed", "screw": "closed",
    "turn-on": "on", "switch": "on", "turn-off": "off", "turn-down": "turned down",
    "cut": "cut", "peel": "peeled", "break": "broken", "rip": "torn", "crush": "crushed",
    "grate": "grated", "divide": "divided", "stab": "pierced", "pour": "poured",
    "mix": "mixed", "fill": "filled", "empty": "empty", "add": "added", "coat": "coated",
    "attach": "attached", "apply": "applied", "sprinkle": "sprinkled", "spray": "sprayed",
    "season": "seasoned", "move": "moved", "throw": "discarded", "eat": "eaten",
    "drink": "drunk", "shake": "shaken", "squeeze": "squeezed", "press": "pressed",
    "flip": "flipped", "turn": "turned", "pull": "pulled", "fold": "folded", "knead": "kneaded",
    "stretch": "stretched", "roll": "rolled", "flatten": "flattened", "form": "shaped",
    "cook": "cooking", "bake": "baking", "filter": "filtered", "check": "checked",
    "look": "checked", "search": "checked", "adjust": "adjusted", "measure": "measured",
    "sharpen": "sharpened", "water": "watered", "unfreeze": "defrosting", "wear": "worn",
}
DEFAULT_STATE = "being used"
# The state of an object a narration names only as where something goes or comes from (a place or
# container after a preposition: "put the cup in the cupboard", "take the cup from the cupboard"):
# nothing is said of its own state, so the editor keeps the one it has ("observed" for a new one).
KEPT_STATE = ""
NEW_STATE = "observed"
# words that name where an object comes from (its destination is named by PREPOSITIONS)
SOURCE_WORDS = ("from", "out of")

# Verbs after which the object leaves the scene: the editor retracts it (DELETE).
RETRACTING_VERBS = {"throw", "eat", "drink"}
# Verbs that leave the object in the hand.
HOLDING_VERBS = {"take", "lift", "hold", "carry", "gather", "choose", "scoop", "remove"}
RELEASING_VERBS = {"put", "insert", "hang", "drop", "let-go", "serve", "set", "throw"}

COLORS = {
    "black", "white", "red", "green", "blue", "yellow", "silver", "grey", "gray", "brown",
    "pink", "orange", "purple", "gold", "transparent", "clear",
}
MATERIALS = {
    "plastic", "wooden", "wood", "metal", "metallic", "glass", "ceramic", "paper", "steel",
    "stainless", "silicone", "rubber", "cardboard", "aluminium", "foil", "cloth",
}
SIZES = {"small", "big", "large", "little", "medium", "mini", "tiny", "huge", "tall", "long", "short"}

# preposition -> relation of the object to what follows it
PREPOSITIONS: list[tuple[str, str]] = [
    ("next to", "ADJACENT_TO"), ("on top of", "ON_TOP_OF"), ("inside", "INSIDE"),
    ("into", "INSIDE"), ("in", "INSIDE"), ("onto", "ON_TOP_OF"), ("on", "ON_TOP_OF"),
    ("under", "BELOW"), ("underneath", "BELOW"), ("below", "BELOW"), ("beneath", "BELOW"),
    ("above", "ABOVE"), ("over", "ABOVE"), ("behind", "BEHIND"), ("beside", "ADJACENT_TO"),
    ("near", "ADJACENT_TO"), ("by", "ADJACENT_TO"), ("in front of", "IN_FRONT_OF"),
]

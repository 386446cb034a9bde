"""Words -> EPIC-KITCHENS verb and noun classes, for reading free text at the class level.

The bundled class tables list, per class, the words annotators used for it ("pick-up", "grab",
"retrieve" -> take; "cabinet", "cupboard" -> cupboard; "board:chopping" -> the chopping board).
`Lexicon.parse` turns a sentence ("They rinsed the mug under the tap, then put it on the rack")
into clauses of (verb class, object classes, place, instrument), so "put-in cup to cupboard",
"places the mug in the cabinet" and "store cup" meet at the class level. The memory stores the
same classes (its narrations were perceived into them), so a reader compares like with like.

Words are folded to a lemma first (plural and -s/-ed/-ing forms, the common irregular verbs), on
both sides: the table's instances and the text.
"""

from __future__ import annotations

import ast
import csv
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

_IRREGULAR = {
    "took": "take", "taken": "take", "put": "put", "threw": "throw", "thrown": "throw", "ate": "eat", "eaten": "eat",
    "drank": "drink", "drunk": "drink", "held": "hold", "cut": "cut", "set": "set", "left": "leave", "got": "get",
    "gotten": "get", "brought": "bring", "began": "begin", "begun": "begin", "shook": "shake", "shaken": "shake",
    "hung": "hang", "split": "split", "dried": "dry", "fried": "fry", "emptied": "empty", "tried": "try",
    "made": "make", "ground": "grind", "spread": "spread", "stuck": "stick", "tore": "tear", "torn": "tear",
    "broke": "break", "broken": "break", "fell": "fall", "fallen": "fall", "dug": "dig", "wrung": "wring",
    "went": "go", "gone": "go", "came": "come", "did": "do", "done": "do", "does": "do", "has": "have",
    "had": "have", "was": "be", "were": "be", "is": "be", "are": "be", "been": "be", "knives": "knife",
    "loaves": "loaf", "halves": "half", "shelves": "shelf", "dishes": "dish", "glasses": "glass",
    "boxes": "box", "peaches": "peach", "tomatoes": "tomato", "potatoes": "potato", "mangoes": "mango",
    "sandwiches": "sandwich", "lunches": "lunch", "children": "child", "teeth": "tooth", "feet": "foot",
    "mice": "mouse", "washes": "wash", "brushes": "brush", "pushes": "push", "mixes": "mix", "fixes": "fix",
    "reaches": "reach", "touches": "touch", "watches": "watch", "scratches": "scratch", "squashes": "squash",
    "rinses": "rinse", "places": "place", "uses": "use", "closes": "close", "sauces": "sauce", "pieces": "piece",
    "slices": "slice", "juices": "juice", "spices": "spice", "lettuces": "lettuce", "cheeses": "cheese",
    "leaving": "leave", "dying": "die", "lying": "lie", "using": "use", "placing": "place", "rinsing": "rinse",
    "closing": "close", "slicing": "slice", "squeezing": "squeeze", "taking": "take", "making": "make",
    "wiping": "wipe", "pouring": "pour", "storing": "store", "having": "have", "being": "be",
}
_DOUBLE_OK = frozenset("lsz")
_TOKEN = re.compile(r"[a-z][a-z0-9]*|[,;.:!?]")
# words that open a clause before its verb ("they then usually first ...")
_LEAD = frozenset("""they he she it person participant usually typically often always first then also just
    has have had does did do to will would directly immediately quickly carefully repeatedly briefly again
    mostly generally sometimes tend tends prefer prefers likes like goes go starts start begins begin keeps keep
    continues continue who that which i we you the a an""".split())
_SPLIT = frozenset({",", ";", ".", ":", "then", "before", "after", "while", "afterwards", "afterward", "and", "or",
                    "but", "followed", "until", "once", "when", "without"})
_PLACE_PREP = frozenset({"at", "in", "into", "on", "onto", "to", "from", "under", "inside", "near", "beside", "over",
                         "toward", "towards", "back", "across", "off", "out"})
_TOOL_PREP = frozenset({"with", "using", "use", "via"})
# instance words of the class tables that are ordinary English far more often than the class
# ("have" is listed under carry, "lead" under wire): not read as that class
_VERB_NOISE = frozenset({"have", "be", "do", "loose", "level", "rise", "cool", "create", "pace", "pout", "lie", "save",
                         "reture", "pose", "dose", "transition", "use", "finish", "wait", "feel", "mark", "form",
                         "prepare", "choose", "increase", "lower", "set"})
_NOUN_NOISE = frozenset({"lead", "measure", "step", "back", "end", "side", "front", "edge", "centre", "center", "content",
                         "stack", "place", "part", "bit", "rest", "way", "time", "thing", "item", "type", "kind",
                         "order", "pattern", "approach", "method", "style", "set", "second", "new", "other", "using",
                         "wash", "cooking", "use", "left", "right", "video", "task", "session", "moment", "sequence",
                         "routine", "prep", "action", "activity"})
_WH = frozenset({"what", "which", "how", "where", "who", "why", "whom", "whose"})
# verbs of aspect: "finishes drying the cup" is about drying
_ASPECT = frozenset({"finish", "stop", "end", "complete", "start", "begin", "continue", "keep", "try", "go"})
_PARTICLES = ("down", "up", "aside", "away", "back", "on", "off", "out", "in", "over", "around", "into", "onto")
# verbs that say an action happened without saying which ("handled the purse"): read, no class
_GENERIC_VERBS = frozenset({"handle", "deal", "work", "interact", "manage", "do", "perform", "approach", "treat"})
_DETERMINERS = frozenset({"the", "a", "an", "its", "their", "his", "her", "this", "that", "each", "one", "every"})
_NEGATION = frozenset({"without", "not", "never", "no", "avoid", "avoids", "avoiding", "instead", "rather", "skip",
                       "skips", "untouched", "except"})
PLACE_CATEGORIES = frozenset({"appliances", "furniture", "storage"})


def lemma(word: str, known: frozenset[str] | None = None) -> str:
    """The base form of a word: irregulars by table, else -ies/-ied/-es/-ed/-ing/-s folded, choosing
    the candidate that is a known word when `known` is given ("placing" -> "place", "stirred" -> "stir")."""
    w = word.lower()
    if w in _IRREGULAR:
        return _IRREGULAR[w]
    cands: list[str] = []
    if w.endswith(("ies", "ied")) and len(w) > 4:
        cands.append(w[:-3] + "y")
    for suffix in ("ing", "ed"):
        if w.endswith(suffix) and len(w) > len(suffix) + 2:
            base = w[: -len(suffix)]
            if len(base) > 2 and base[-1] == base[-2] and base[-1] not in _DOUBLE_OK:
                cands.append(base[:-1])
            cands += [base, base + "e"]
    if w.endswith("es") and len(w) > 4:
        cands += [w[:-2], w[:-1]] if w[:-2].endswith(("s", "x", "z", "ch", "sh")) else [w[:-1], w[:-2]]
    elif w.endswith("s") and not w.endswith(("ss", "us", "is")) and len(w) > 3:
        cands.append(w[:-1])
    if not cands:
        return w
    if known is not None:
        for c in cands:
            if c in known:
                return c
        if w in known:
            return w
    return cands[0]


@dataclass
class Clause:
    """One action of a sentence, as classes: verb, objects (in order), the place it happens at or
    goes to, the instrument used, and whether the sentence negates it ("without washing it")."""

    verb: str | None
    nouns: list[str] = field(default_factory=list)
    place: str | None = None
    instrument: str | None = None
    negated: bool = False
    words: list[str] = field(default_factory=list)  # the clause's content lemmas (for what the classes miss)

    def objects(self) -> list[str]:
        return [n for n in self.nouns if n not in (self.place, self.instrument)]


class Lexicon:
    """EPIC verb and noun classes with their instance words, and a clause parser over them."""

    def __init__(self, verbs: dict[str, list[str]], nouns: dict[str, list[str]], noun_category: dict[str, str],
                 verb_category: dict[str, str] | None = None):
        self.noun_category = noun_category
        self.verb_category = verb_category or {}
        self.verb_keys = list(verbs)
        self.noun_keys = list(nouns)
        vocab: set[str] = set()
        for inst in [*(i for v in verbs.values() for i in v), *verbs, *(i for v in nouns.values() for i in v), *nouns]:
            vocab.update(re.findall(r"[a-z]+", inst.lower()))
        vocab.update(("place", "store", "use", "rinse", "scrub", "clean", "cook", "handle", "prepare", "leave"))
        self.known = frozenset(vocab)
        self.verb_phrases: dict[tuple[str, ...], str] = {}
        for key, instances in verbs.items():
            for inst in [key, *instances]:
                words = tuple(lemma(w, self.known) for w in re.findall(r"[a-z]+", inst.lower()))
                if words and not (len(words) == 1 and words[0] in _VERB_NOISE and words[0] != key):
                    self.verb_phrases.setdefault(words, key)
        # common paraphrases the annotators' instances lack
        for words, key in _VERB_EXTRA.items():
            self.verb_phrases.setdefault(tuple(lemma(w, self.known) for w in words.split()), key)
        self.noun_phrases: dict[tuple[str, ...], str] = {}
        heads: dict[str, str] = {}
        for key, instances in nouns.items():
            for inst in [key, *instances]:
                parts = [p for p in inst.lower().split(":") if p]
                if not parts:
                    continue
                words = [w for p in reversed(parts[1:]) for w in re.findall(r"[a-z]+", p)] + re.findall(r"[a-z]+", parts[0])
                phrase = tuple(lemma(w, self.known) for w in words)
                if phrase and not (len(phrase) == 1 and phrase[0] in _NOUN_NOISE):
                    self.noun_phrases.setdefault(phrase, key)
            head = tuple(lemma(w, self.known) for w in re.findall(r"[a-z]+", key.split(":")[0]))
            heads.setdefault(head, key) if head else None
        for head, key in heads.items():
            if not (len(head) == 1 and head[0] in _NOUN_NOISE):
                self.noun_phrases.setdefault(head, key)
        for words, key in _NOUN_EXTRA.items():
            if key in nouns:
                self.noun_phrases.setdefault(tuple(lemma(w, self.known) for w in words.split()), key)
        # classes a paraphrase uses for one another's actions ("sets it down" is putting it down)
        self.verb_phrases = {k: VERB_ALIASES.get(v, v) for k, v in self.verb_phrases.items()}
        self._max_verb = max(len(p) for p in self.verb_phrases)
        self._max_noun = max(len(p) for p in self.noun_phrases)
        self._parsed: dict[str, list[Clause]] = {}  # a reader parses the same memory lines again and again
        self._nouns: dict[str, list[str]] = {}

    @classmethod
    def load(cls, folder: Path | None = None) -> Lexicon:
        return _load(str(folder) if folder else "")

    # -- classes of single words / phrases ---------------------------------------------------
    def lemmas(self, text: str) -> list[str]:
        return [t if not t.isalpha() else lemma(t, self.known) for t in _TOKEN.findall(text.lower().replace("_", " "))]

    def verb_class(self, text: str) -> str | None:
        toks = self.lemmas(text.replace("-", " "))
        hit = self._match(toks, 0, self.verb_phrases, self._max_verb)
        return hit[1] if hit else None

    def noun_classes(self, text: str) -> list[str]:
        """Every noun class named in the text, in order (longest phrases first)."""
        hit = self._nouns.get(text)
        if hit is None:
            hit = self._nouns[text] = self._noun_classes(text)
            if len(self._nouns) > 200_000:
                self._nouns.clear()
        return list(hit)

    def _noun_classes(self, text: str) -> list[str]:
        toks = self.lemmas(text.replace("-", " "))
        out, i = [], 0
        while i < len(toks):
            hit = self._match(toks, i, self.noun_phrases, self._max_noun)
            if hit:
                out.append(hit[1])
                i += hit[0]
            else:
                i += 1
        return out

    def verb(self, word_or_class: str | None) -> str | None:
        """A memory's action word (a class key, or a verb as narrated) as its class."""
        if not word_or_class:
            return None
        w = word_or_class.lower()
        if w in self.verb_category or w in VERB_ALIASES:
            return VERB_ALIASES.get(w, w)
        return self.verb_class(w)

    def same_category(self, a: str | None, b: str | None) -> bool:
        return bool(a and b and self.verb_category.get(a) and self.verb_category.get(a) == self.verb_category.get(b))

    def is_place(self, noun: str) -> bool:
        return self.noun_category.get(noun, "") in PLACE_CATEGORIES

    @staticmethod
    def _match(toks: list[str], i: int, table: dict[tuple[str, ...], str], longest: int) -> tuple[int, str] | None:
        for n in range(min(longest, len(toks) - i), 0, -1):
            key = tuple(toks[i:i + n])
            if key in table:
                return n, table[key]
        return None

    # -- sentences ------------------------------------------------------------------------------
    def parse(self, text: str) -> list[Clause]:
        """Clauses of a sentence in the order they happen ("Y after X" is X then Y). Question
        clauses ("what do they do next?") are not actions and are left out; `question_words`
        returns them."""
        hit = self._parsed.get(text)
        if hit is None:
            hit = self._parsed[text] = self._parse(text)
            if len(self._parsed) > 200_000:
                self._parsed.clear()
        return [Clause(c.verb, list(c.nouns), c.place, c.instrument, c.negated, list(c.words)) for c in hit]

    def _parse(self, text: str) -> list[Clause]:
        clauses: list[tuple[str | None, Clause]] = []
        negate_next = False
        for marker, words in self._segments(text):
            if words and words[0] in _WH:
                continue
            if not words:
                if marker in ("without",):
                    negate_next = True
                continue
            c = self._clause(words)
            if c.verb is None and not c.nouns:
                continue
            if c.verb is None and clauses and marker in ("and", "or", ","):
                prev = clauses[-1][1]  # "the bowl and the plate": more objects of the same action
                prev.nouns += [n for n in c.nouns if n not in prev.nouns]
                prev.words += c.words
                continue
            c.negated = c.negated or negate_next or marker == "without"
            negate_next = False
            clauses.append((marker, c))
        ordered: list[Clause] = []
        for marker, c in clauses:
            if marker == "after" and ordered:  # "Y after X": X happened first
                ordered.insert(len(ordered) - 1, c)
            else:
                ordered.append(c)
        return ordered

    def _segments(self, text: str) -> list[tuple[str | None, list[str]]]:
        toks = self.lemmas(text.replace("-", " ").replace("'s", ""))
        segments: list[tuple[str | None, list[str]]] = [(None, [])]
        for t in toks:
            if t in _SPLIT:
                segments.append((t, []))
            else:
                segments[-1][1].append(t)
        return segments

    def verb_words(self, text: str) -> list[str | None]:
        """Per clause of `parse(text)`, the word (lemma) that names its verb: "lather" for the *wash*
        of "lathers the pan", "pick" for the *take* of "picks it up"; None where no word does."""
        toks = self.lemmas(text.replace("-", " ").replace("'s", ""))
        used: set[int] = set()
        out: list[str | None] = []
        for c in self.parse(text):
            at = None
            if c.verb:
                at = next((j for j in range(len(toks)) if j not in used and toks[j].isalpha()
                           and self.verb_class(" ".join(toks[j:j + 3])) == c.verb), None)
            if at is not None:
                used.add(at)
            out.append(toks[at] if at is not None else None)
        return out

    def question_words(self, text: str) -> list[str]:
        """The lemmas of the question's wh-clauses ("what do they usually do next")."""
        return [w for _, words in self._segments(text) if words and words[0] in _WH for w in words]

    def question_nouns(self, text: str) -> list[str]:
        """The object classes the question's wh-clauses name. A generic verb is an object only after
        a determiner ("the handle of the pan"); as a verb ("how does P01 handle the bowl", "what
        handling pattern") it names no object."""
        kept, prev = [], ""
        for _, words in self._segments(text):
            if not words or words[0] not in _WH:
                continue
            for w in words:
                if not (w in _GENERIC_VERBS and prev not in _DETERMINERS):
                    kept.append(w)
                prev = w
        return self.noun_classes(" ".join(kept))

    def _clause(self, words: list[str]) -> Clause:
        i = 0
        negated = False
        while i < len(words) and (words[i] in _LEAD or words[i] in _NEGATION or re.fullmatch(r"p\d+(_\d+)?", words[i])):
            negated = negated or words[i] in _NEGATION
            i += 1
        verb = None
        hit = self._match(words, i, self.verb_phrases, self._max_verb)
        if hit is None:  # a verb a little later ("the person then quickly rinses ...")
            for j in range(i + 1, min(i + 4, len(words))):
                hit = self._match(words, j, self.verb_phrases, self._max_verb)
                if hit and not self._match(words, j, self.noun_phrases, self._max_noun):
                    i = j
                    break
                hit = None
        if hit and words[i] in _ASPECT and i + hit[0] < len(words):
            then = self._match(words, i + hit[0], self.verb_phrases, self._max_verb)
            if then:  # "finishes drying": the action is drying
                i += hit[0]
                hit = then
        if hit:
            verb = hit[1]
            head = words[i]
            i += hit[0]
            if hit[0] == 1:  # a particle later in the clause: "turn the tap on", "set the cup down"
                for w in words[i:i + 4]:
                    if w in _PARTICLES and (head, w) in self.verb_phrases:
                        verb = self.verb_phrases[(head, w)]
                        break
        elif i < len(words) and words[i] in _GENERIC_VERBS:
            i += 1
        nouns: list[str] = []
        place = instrument = None
        role = None
        content = []
        while i < len(words):
            w = words[i]
            if w in _NEGATION:
                negated = True
            if w in _PLACE_PREP:
                role = "place"
            elif w in _TOOL_PREP:
                role = "tool"
            hit = self._match(words, i, self.noun_phrases, self._max_noun)
            if hit:
                n = hit[1]
                nouns.append(n)
                if role == "tool" and instrument is None:
                    instrument = n
                elif (role == "place" or self.is_place(n)) and place is None and (role == "place" or nouns[:-1]):
                    place = n
                content += words[i:i + hit[0]]
                i += hit[0]
                continue
            if w.isalpha() and len(w) > 2 and w not in _LEAD:
                content.append(w)
            i += 1
        return Clause(verb, nouns, place, instrument, negated, content)


# class keys read as another class: EPIC's "set" is mostly set-timer, but text "sets it down" is put
VERB_ALIASES = {"set": "put"}

_VERB_EXTRA = {
    "set aside": "put", "set down": "put", "set back": "put", "put away": "put",
    "place": "put", "sets down": "put", "store": "put", "stash": "put", "leave": "put",
    "rinse": "wash", "clean": "wash", "lather": "wash", "soap": "wash", "grab": "take", "retrieve": "take",
    "collect": "take", "fetch": "take", "get": "take", "pick up": "take", "pick": "take", "stir": "mix",
    "whisk": "mix", "combine": "mix", "chop": "cut", "slice": "cut", "dice": "cut", "trim": "cut", "split": "divide",
    "transfer": "move", "carry": "carry", "toss": "throw", "discard": "throw", "dispose": "throw", "bin": "throw",
    "switch on": "turn-on", "switch off": "turn-off", "boil": "cook", "fry": "cook", "heat": "cook", "simmer": "cook",
    "saute": "cook", "roast": "cook", "dry": "dry", "towel": "dry", "spoon": "scoop", "ladle": "scoop", "tip": "pour",
    "drain": "filter", "strain": "filter", "sieve": "filter", "season": "sprinkle", "salt": "sprinkle", "taste": "eat",
    "sip": "drink", "squish": "squeeze", "flatten": "flatten", "stack": "put", "load": "insert", "unload": "take",
    "hang": "hang", "wring": "squeeze", "knead": "knead", "shape": "form", "mould": "form", "mold": "form",
    "cover": "put", "uncover": "uncover", "seal": "close", "shut": "close", "flip": "flip", "turn over": "flip",
    "scrape": "scrape", "wipe": "wash", "mop": "wash", "sponge": "wash", "scrub": "scrub", "soak": "soak",
    "check": "check", "inspect": "check", "examine": "check", "look": "look", "read": "look", "adjust": "adjust",
    "tidy": "move", "arrange": "move", "organise": "move", "organize": "move", "stage": "put", "portion": "scoop",
    "serve": "serve", "plate": "serve", "grate": "grate", "peel": "peel", "fill": "fill", "refill": "fill",
    "top up": "fill", "empty": "empty", "pour out": "empty", "spray": "spray", "sprinkle": "sprinkle",
    "spread": "apply", "smear": "apply", "brush": "brush", "mash": "crush", "crush": "crush", "press": "press",
    "open": "open", "unscrew": "unscrew", "screw": "screw", "close": "close", "lid": "close",
}
_NOUN_EXTRA = {
    "tap water": "tap", "faucet": "tap", "cabinet": "cupboard", "cupboards": "cupboard", "counter": "top",
    "countertop": "top", "worktop": "top", "work surface": "top", "stove": "hob", "stovetop": "hob", "burner": "hob",
    "cooker": "hob", "frying pan": "pan", "skillet": "pan", "saucepan": "pan", "wok": "pan", "mug": "cup",
    "chopping board": "board:chopping", "cutting board": "board:chopping", "drying rack": "rack:drying",
    "dish rack": "rack:drying", "dish brush": "brush", "washing up liquid": "liquid:washing", "dish soap": "liquid:washing",
    "bin": "bin", "trash": "bin", "rubbish bin": "bin", "garbage": "bin", "bowl": "bowl", "dishwasher": "dishwasher",
    "kitchen towel": "towel:kitchen", "paper towel": "towel:kitchen", "tea towel": "towel", "cloth": "cloth",
}


@lru_cache(maxsize=2)
def _load(folder: str) -> Lexicon:
    from memora_graph.paths import epic_dir

    root = Path(folder) if folder else epic_dir()
    verbs: dict[str, list[str]] = {}
    nouns: dict[str, list[str]] = {}
    category: dict[str, str] = {}
    verb_category: dict[str, str] = {}
    for kind, out in (("verb", verbs), ("noun", nouns)):
        with open(root / f"{kind}_classes.csv", newline="", encoding="utf-8") as fh:
            for row in csv.DictReader(fh):
                try:
                    instances = ast.literal_eval(row.get("instances") or "[]")
                except (ValueError, SyntaxError):
                    instances = []
                out[row["key"]] = [str(i) for i in instances if isinstance(i, str)]
                (category if kind == "noun" else verb_category)[row["key"]] = row.get("category", "")
    return Lexicon(verbs, nouns, category, verb_category)

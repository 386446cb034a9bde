"""What an open question (one without answer choices) asks for, read at the level of EPIC classes:
the word-level reading the typed query's parser (`query.parse`) builds its `Query` from.

`parse_open` turns a question into an `OpenQuestion`: the kind of answer it wants and the action
it is about, as verb and noun classes (`perceive.lexicon`, so "chopping board", "cutting board"
and "board:chopping" meet), with the order asked (last / first / usual), a video and a time it
names, and who it is about. The kind comes from the question's structure, not from a wording:

- count    "how many times / how often / number of times" -> a number (the records counted)
- time     "when / in which video / at what point" -> a video and time (last or first)
- place    "where / in what place / which surface" -> a place (where it was last put, or kept)
- yesno    a question opening on an auxiliary ("has / did / does / is ...") -> yes, or no
- state    "what state / condition ..." of an object, at a time of a video -> state and place
- activity "what did P do / was P doing" in a named video (around a time) -> the activity log
- next     "after X / next / then / follow / lead to" -> the next actions with their share
- routine  "how does P (usually) do G / what steps / procedure" -> the ordered steps
- actions  anything else about an object or action ("what does P do with X") -> actions, shares
- general  nothing about a person and no memory cue ("what is the capital of France?")

Whether the subject is in this person's memory is the answerer's business (`query.answer`): the
parser says what is asked, not whether memory holds it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from memora_graph.agent.reading import stem_of
from memora_graph.perceive.lexicon import Lexicon, lemma

KINDS = ("count", "time", "place", "yesno", "state", "activity", "next", "routine", "actions", "general")

_VIDEO = re.compile(r"\bP\d{2}_\d{2,3}\b", re.I)
_PERSON = re.compile(r"\bP(\d{2})\b(?!_)", re.I)
_CLOCK = re.compile(r"\b(\d{1,2}):(\d{2})(?::(\d{2}(?:\.\d+)?))?\b")
_SECONDS = re.compile(r"\b(\d+(?:\.\d+)?)\s*(seconds?|secs?|s|minutes?|mins?|m)\b", re.I)

# who a question is about: the person wearing the camera, however it is named
_PERSON_WORDS = frozenset("""they them their theirs themselves he him his she her hers herself himself person
    participant i me my mine myself we us our user wearer cook individual subject someone somebody""".split())
_AUX = frozenset({"have", "do", "be", "can", "could", "will", "would", "should", "may", "might", "shall", "must"})
_WH = frozenset({"what", "which", "where", "how", "who", "whom", "whose", "why", "when"})
_VIDEO_WORDS = frozenset({"video", "recording", "record", "session", "footage", "episode", "day",
                          "occasion", "visit"})
_TIME_WORDS = frozenset({"time", "moment", "point", "timestamp", "minute", "second"})
_PLACE_WORDS = frozenset({"place", "location", "spot", "surface", "area", "container", "appliance", "position",
                          "storage", "destination"})
_KEEP_WORDS = frozenset({"keep", "kept", "store", "stored", "storing", "stash", "leave", "left", "located", "locate",
                         "find", "found", "live", "belong", "go", "end", "put", "place", "set", "stow", "stowed"})
_STATE_WORDS = frozenset({"state", "condition", "status", "shape"})
_NEXT_WORDS = frozenset({"next", "after", "afterwards", "afterward", "then", "follow", "subsequently", "lead",
                         "once", "following", "later", "straight"})
_ROUTINE_WORDS = frozenset({"step", "steps", "procedure", "routine", "process", "method", "approach", "sequence",
                            "workflow", "recipe", "order", "stage", "go"})
_LAST = frozenset({"last", "latest", "recent", "recently", "final", "finally", "previous", "lately"})
_FIRST = frozenset({"first", "earliest", "initially", "start", "begin", "beginning", "originally"})
_USUAL = frozenset({"usually", "typically", "normally", "generally", "often", "always", "tend", "habitually",
                    "regularly", "commonly", "mostly", "prefer", "like", "routinely", "customarily"})
_FROM = frozenset({"from", "out"})
# words that frame a question rather than name its action or objects (dropped before the
# action is parsed, so "in which recording did P01 first cut the onion" reads as "cut the onion")
_SCAFFOLD = _WH | _USUAL | _LAST | _FIRST | _VIDEO_WORDS | _TIME_WORDS | _STATE_WORDS | _AUX | \
    (_PLACE_WORDS - {"container", "appliance", "storage"}) | (_ROUTINE_WORDS - {"recipe"}) | frozenset(
    """ever many much often times number count tally any record evidence sign trace there show shows
    instance occasion happen ago far so go separate different distinct individual total whole entire""".split())
# words a question is made of that name neither an action nor an object
_FUNCTION = frozenset("""a an the of to in on at for with by from into onto out up down off over under about as
    and or but if so than that this these those there here it its is be do have not no any some all each every
    ever never also just still yet again already much many often time times number count total amount
    what which where how who whom whose why when whenever wherever usual usually typically normally generally
    last first latest earliest recent recently most least more less very really actually exactly roughly about
    around approximately near close nearly right left back away thing things stuff something anything item items
    object objects video videos recording recordings session sessions clip footage episode day days occasion
    occasions kitchen memory record records recorded show shows seen see saw watch watched notice noticed happen
    happened happening occur occurred during while within throughout before after next then afterwards once
    following follow followed lead leads usually tend tends prefer prefers like likes kind sort type way ways
    keep kept store stored leave left located find found belong belongs end ended place placed put set stow
    state condition status step steps procedure routine process method approach sequence workflow order
    moment point timestamp minute minutes second seconds hour hours can could will would should may might shall
    must does did done doing has had having was were are am been being get got
    go goes went going typically generally overall exist exists existed evidence sign trace instance
    instances case cases mention mentioned able use used using uses now currently today yesterday tonight
    earlier lately moment right one ones long spend spent spending""".split())


FUNCTION_WORDS = _FUNCTION  # words a question is made of that name neither an action nor an object
PERSON_WORDS = _PERSON_WORDS  # words that refer to the person asked about
SCAFFOLD_WORDS = _SCAFFOLD | _LAST | _FIRST | _USUAL | _NEXT_WORDS | frozenset(
    "action actions activity activities name thing things final previous".split())  # words that frame a question


@dataclass
class OpenQuestion:
    """One open question as what it asks (`kind`) and the action and objects it is about."""

    text: str
    kind: str
    verbs: list[str] = field(default_factory=list)  # verb classes of the asked action (trigger for `next`)
    nouns: list[str] = field(default_factory=list)  # object classes it is about, in order
    place: str | None = None  # a place the question names ("in the sink")
    order: str = "usual"  # last | first | usual
    source: bool = False  # place asked is where it was taken from ("where ... from")
    videos: list[str] = field(default_factory=list)
    time: float | None = None  # seconds into the video
    persons: list[str] = field(default_factory=list)  # participant ids named ("P01")
    about_person: bool = False  # names or refers to the person whose memory is asked
    unknown: list[str] = field(default_factory=list)  # content words no EPIC class knows ("chainsaw")
    unit: str = "times"  # count: times | videos
    asked: str = ""  # the kind asked, when the question was then read as general knowledge

    @property
    def verb(self) -> str | None:
        return self.verbs[0] if self.verbs else None

    @property
    def has_subject(self) -> bool:
        return bool(self.verbs or self.nouns)


def seconds_in(text: str) -> float | None:
    """The first time a text names ("01:05", "1:02:03", "90 seconds", "2 minutes"), in seconds."""
    return _seconds(text)


def _seconds(text: str) -> float | None:
    m = _CLOCK.search(text)
    if m:
        a, b, c = m.group(1), m.group(2), m.group(3)
        return int(a) * 3600 + int(b) * 60 + float(c) if c else int(a) * 60 + int(b)
    for m in _SECONDS.finditer(text):
        unit = m.group(2).lower()
        if unit == "m" and not re.search(r"\d\s*m\b", m.group(0)):
            continue
        value = float(m.group(1))
        return value * 60 if unit.startswith("m") else value
    return None


def _kind(toks: list[str], words: set[str], videos: list[str], time: float | None, nouns: list[str]) -> tuple[str, str]:
    """The kind of answer asked, and for counts the unit."""
    joined = " ".join(toks)
    head = [t for t in toks if t.isalpha()][:1]
    opens_aux = bool(head) and head[0] in _AUX
    wh = [t for t in toks if t in _WH]
    if "whereabouts" in words or "whereabout" in words:
        wh.insert(0, "where")
    if re.search(r"\bhow (many|much)\b", joined) or re.search(r"\bhow (often|frequently)\b", joined) or \
            re.search(r"\bnumber of\b", joined) or (words & {"count", "tally"} and not opens_aux):
        m = re.search(r"\b(how many|number of) (\w+)(?: (\w+))?", joined)
        units = _VIDEO_WORDS - {"occasion", "visit", "day"}
        unit = "videos" if m and (m.group(2) in units or (m.group(3) in units and m.group(2) not in ("time", "times")))\
            else "times"
        return "count", unit
    if not videos and ("when" in wh and not re.search(r"\bwhen (they|he|she|p\d+|the person|someone)\b", joined)
                       or re.search(r"\b(which|what)\b( \w+){0,3} (" + "|".join(sorted(_VIDEO_WORDS | _TIME_WORDS)) +
                                    r")\b", joined)
                       or re.search(r"\b(" + "|".join(sorted(_LAST | _FIRST)) + r")( \w+){0,1} (" +
                                    "|".join(sorted(_VIDEO_WORDS - {"day", "occasion", "visit"})) + r")\b", joined)):
        if "when" in wh or not re.search(r"\bin (which|what)( \w+)? (" + "|".join(sorted(_VIDEO_WORDS)) +
                                         r")\b.*\b(what|which|where|how)\b", joined):
            return "time", ""
    if "where" in wh or re.search(r"\b(which|what)\b( \w+){0,3} (" + "|".join(_PLACE_WORDS) + r")\b", joined):
        return "place", ""
    if words & _STATE_WORDS and (nouns or videos) and not opens_aux:
        return "state", ""
    if opens_aux and not (wh and toks.index(wh[0]) < 3):
        return "yesno", ""
    if videos and not (words & _NEXT_WORDS and not time):
        return "activity", ""
    if words & (_ROUTINE_WORDS - {"go", "order", "sequence"}):
        return "routine", ""
    if words & _NEXT_WORDS or joined.startswith(("after ", "once ")):
        return "next", ""
    if re.search(r"\bhow (do|does|did|would|will|can|is|are)\b", joined) or words & (_ROUTINE_WORDS - {"go"}):
        return "routine", ""
    if wh and wh[0] in ("who", "why", "whom", "whose"):
        return "general", ""
    return "actions", ""


def parse_open(question: str, lex: Lexicon, participant: str | None = None) -> OpenQuestion:
    """The question as what it asks (see the module docstring)."""
    text = stem_of(question).strip()
    low = text.lower()
    videos = list(dict.fromkeys(v.upper() for v in _VIDEO.findall(text)))
    persons = list(dict.fromkeys(f"P{m}" for m in _PERSON.findall(text)))
    time = _seconds(_VIDEO.sub(" ", text))
    clean = _verb_forms(_FILLER_PHRASES.sub(" ", _VIDEO.sub(" ", text).replace("-", " ").replace("'s", "")), lex)
    toks = lex.lemmas(_drop_gerunds(clean, lex, keep_verbs=True))
    raw = re.findall(r"[a-z]+", _VIDEO.sub(" ", low))
    words = set(toks) | set(raw)
    about = bool(persons) or bool(videos) or _refers_to_person(raw)
    # the action and objects: the question without its question words, parsed into clauses
    body = [t for t in toks if not (t in _SCAFFOLD or re.fullmatch(r"p\d+", t)
                                    or (t.endswith("ly") and len(t) > 4 and not lex.noun_classes(t)
                                        and not lex.verb_class(t)))]
    tail = [w for w in raw if not re.fullmatch(r"p\d+", w) and w not in ("by",) and w not in _PERSON_WORDS]
    last = tail[-2:-1] if len(tail) > 1 and tail[-1] in _PARTICLES else tail[-1:]  # "was the tap turned on"
    participle = bool(last) and (last[0].endswith(("ed", "en", "wn")) or last[0] in ("put", "cut", "set", "shut"))
    clauses = _clauses(body, lex, passive=participle and bool(set(raw) & {"was", "were", "been", "being"}))
    nouns = list(dict.fromkeys(n for c in clauses for n in c.nouns))
    if not nouns:  # objects the clauses missed (a question that names no action)
        rest = re.sub(r"^\s*(can|will|could|would|may|must)\b", " ", clean, flags=re.I)
        nouns = list(dict.fromkeys(noun_classes(lex, _drop_gerunds(rest, lex, keep_verbs=False))))
    verbs = list(dict.fromkeys(c.verb for c in clauses if c.verb and c.verb != "transition"))
    asking = _asking_sentence(clean)
    ktoks = lex.lemmas(asking) if asking != clean else toks
    kind, unit = _kind(ktoks, set(ktoks) | set(re.findall(r"[a-z]+", asking.lower())) | (words & {"whereabouts"}),
                       videos, time, nouns)
    if asking != clean and kind in ("actions", "routine") and verbs and {"what", "do"} <= set(ktoks):
        kind = "next"  # "P07 has just rinsed the colander. What are they likely to do now?"
    place = next((c.place for c in clauses if c.place and c.place in c.nouns[1:]), None)
    if kind == "next":
        # the trigger is the clause after "after" / "once" / "when", or the first action named
        trig = _trigger(toks, lex)
        if trig is not None and trig.verb:
            verbs = [trig.verb] + [v for v in verbs if v != trig.verb]
            nouns = list(dict.fromkeys(trig.nouns + nouns))
    order = "last" if words & _LAST or "now" in words or "currently" in words else \
        "first" if words & _FIRST and kind in ("time", "place", "count") else "usual"
    if kind == "routine" and "first" in words:
        order = "usual"
    known = lex.known
    unknown = [w for w in raw if len(w) > 2 and w.isalpha() and w not in _FUNCTION and w not in _PERSON_WORDS
               and w not in known and lex.lemmas(w)[0] not in known and w not in _USUAL and w not in _LAST
               and w not in _FIRST and w not in _NEXT_WORDS]
    source = bool(words & _FROM) and kind == "place" and not (verbs and verbs[0] in ("put", "insert", "throw"))
    if kind == "place" and nouns and place is None and len(nouns) > 1 and lex.is_place(nouns[-1]) and \
            not (verbs and verbs[0] in ("take", "remove")):
        place = None  # "where is the chopping board kept": the object is the subject
    oq = OpenQuestion(text=text, kind=kind, verbs=verbs, nouns=nouns, place=place, order=order, source=source,
                      videos=videos, time=time, persons=persons, about_person=about, unknown=unknown, unit=unit)
    if _general(oq, toks, words):
        oq.asked, oq.kind = oq.kind, "general"
    return oq


_REFERENCE_NOUNS = frozenset({"person", "participant", "user", "wearer", "cook", "individual", "subject"})


def _refers_to_person(raw: list[str]) -> bool:
    """A pronoun, or "the person / this participant" (not "the first person on the moon")."""
    for i, w in enumerate(raw):
        if w in _PERSON_WORDS - _REFERENCE_NOUNS - {"someone", "somebody"}:
            return True
        if w in _REFERENCE_NOUNS and i and raw[i - 1] in ("the", "this", "that", "our"):
            return True
    return False


_FILLER_PHRASES = re.compile(r"\b(in total|in all|all together|altogether|overall|so far|to date|at all|at any point|"
                             r"at some point|give a count|name the video|before now)\b", re.I)
_PARTICLES = frozenset({"on", "off", "up", "down", "out", "away", "over", "in", "back"})
_DETERMINERS = frozenset({"the", "a", "an", "their", "his", "her", "its", "some", "any", "that", "this", "my", "your",
                          "our"})


def noun_classes(lex: Lexicon, text: str) -> list[str]:
    """`lex.noun_classes`, except that a word which is itself a class key reads as that class
    ("top" is the worktop class, though EPIC also lists it under another class's words)."""
    out = lex.noun_classes(text)
    return [_KEY_FIX(lex).get(n, {}).get(w, n) for n, w in _pairs(lex, text, out)]


def _pairs(lex: Lexicon, text: str, classes: list[str]) -> list[tuple[str, str]]:
    """Each class with the key word it should read as ('' to keep it): a one-word class key
    standing alone, not inside a compound ("the top" is the top; "plastic wrap" stays a compound)."""
    hits = _key_hits(lex, lex.lemmas(text))
    return [(n, hits.get(n, "")) for n in classes]


def _key_hits(lex: Lexicon, toks: list[str]) -> dict[str, str]:
    """class -> the first key word in `toks` that names it standing alone; one pass over the words
    (a class per word looked up, not a pass over the words per class: linear in the question)."""
    words = _KEY_WORDS(lex)
    hits: dict[str, str] = {}
    for i, w in enumerate(toks):
        for n in words.get(w, ()):
            if n in hits:
                continue
            prev = toks[i - 1] if i else ""
            if not (prev.isalpha() and prev not in _FUNCTION and lex.noun_classes(f"{prev} {w}") == [n]):
                hits[n] = w
    return hits


_WORDS_CACHE: dict[int, dict[str, list[str]]] = {}


def _KEY_WORDS(lex: Lexicon) -> dict[str, list[str]]:
    """word -> the classes `_KEY_FIX` reads it for."""
    got = _WORDS_CACHE.get(id(lex))
    if got is None:
        got = {}
        for n, words in _KEY_FIX(lex).items():
            for w in words:
                got.setdefault(w, []).append(n)
        _WORDS_CACHE[id(lex)] = got
    return got


def fix_keys(lex: Lexicon, text: str, classes) -> list[str]:
    """Classes of `text` (from `lex.parse`) with the class-key reading of `noun_classes`."""
    return [_KEY_FIX(lex).get(n, {}).get(w, n) for n, w in _pairs(lex, text, list(classes))]


_KEY_CACHE: dict[int, dict[str, dict[str, str]]] = {}


def _KEY_FIX(lex: Lexicon) -> dict[str, dict[str, str]]:
    """class read -> {word: the class that word names as a key} for one-word class keys that the
    lexicon reads as another class."""
    got = _KEY_CACHE.get(id(lex))
    if got is None:
        got = {}
        for key in lex.noun_keys:
            if ":" in key or not key.isalpha():
                continue
            read = lex.noun_classes(key)
            if read and read[0] != key and len(read) == 1:
                got.setdefault(read[0], {})[key] = key
        _KEY_CACHE[id(lex)] = got
    return got


def _clauses(body: list[str], lex: Lexicon, passive: bool = False):
    """The body's clauses; a passive ("the water was last poured by P01", "how many times was the
    tap moved") or a verb the lexicon also reads as an object ("brushing the brush", "peel the
    onion") found by its position."""
    clauses = lex.parse(" ".join(body))
    words = [t for t in body if t.isalpha()]
    if passive and len(words) > 2 and words[-1] in _PARTICLES and lex.verb_class(" ".join(words[-2:])):
        nouns = noun_classes(lex, " ".join(words[:-2]))  # "how many times was the tap turned on"
        if nouns:
            from memora_graph.perceive.lexicon import Clause

            return [Clause(lex.verb_class(" ".join(words[-2:])), nouns)]
    if passive and len(words) > 1 and words[-1] != "by" and lex.verb_class(words[-1]):
        nouns = noun_classes(lex, " ".join(words[:-1]))
        if nouns:
            from memora_graph.perceive.lexicon import Clause

            return [Clause(lex.verb_class(words[-1]), nouns)]
    if "by" in body:
        j = body.index("by")
        if j > 0 and lex.verb_class(body[j - 1]) and all(t in _DETERMINERS or t in _PERSON_WORDS or not t.isalpha()
                                                      for t in body[j + 1:]):
            verb = lex.verb_class(body[j - 1])
            nouns = noun_classes(lex, " ".join(body[:j - 1]))
            if nouns:
                from memora_graph.perceive.lexicon import Clause

                return [Clause(verb, nouns)]
    if not any(c.verb and c.verb != "transition" for c in clauses):
        for i, t in enumerate(body[:-1]):
            after = body[i + 2] if body[i + 1] in _PARTICLES and i + 2 < len(body) else body[i + 1]
            if lex.verb_class(t) and after in _DETERMINERS:
                again = lex.parse(" ".join(body[i:]))
                if any(c.verb for c in again):
                    return again
    hits = _key_hits(lex, lex.lemmas(" ".join(body)))  # once for the body, not once per clause
    fix = _KEY_FIX(lex)
    for c in clauses:
        c.nouns = [fix.get(n, {}).get(hits.get(n, ""), n) for n in c.nouns]
        if c.place:
            c.place = fix.get(c.place, {}).get(hits.get(c.place, ""), c.place)
    return clauses


def _asking_sentence(text: str) -> str:
    """The sentence that asks ("P04 has just closed the oven. What will they do next?" asks the
    second; "How often did P01 peel the onion? Give a count." the first); the whole text when it
    is one sentence."""
    parts = [p.strip() for p in re.findall(r"[^.?!]+[.?!]?", text) if p.strip(" .?!")]
    if len(parts) < 2:
        return text
    asked = [p for p in parts if p.endswith("?")]
    return asked[-1] if asked else text


def _verb_forms(text: str, lex: Lexicon) -> str:
    """-ed / -ing words read as the verb they inflect when the default lemma is no verb
    ("scraped" is scrape, not the noun scrap)."""
    out = []
    for w in text.split():
        low = w.lower()
        lem = lemma(low, lex.known)
        if low.endswith(("ed", "ing")) and (lex.verb_class(lem) is None or lex.noun_classes(lem)):
            base = low[:-2] if low.endswith("ed") else low[:-3]
            for cand in (base + "e", base, base[:-1] if len(base) > 2 and base[-1] == base[-2] else ""):
                if cand and lex.verb_class(cand) and not lex.noun_classes(cand):
                    w = cand
                    break
        out.append(w)
    return " ".join(out)


def _drop_gerunds(text: str, lex: Lexicon, keep_verbs: bool) -> str:
    """The text without -ing / -ed words that would read as an object ("handling the salad" is no
    handle, "peeling a potato" no peel) unless they open a compound ("chopping board", "frying
    pan"); with `keep_verbs`, words the lexicon reads as an action stay (the parser wants them)."""
    words = text.split()
    out = []
    for i, w in enumerate(words):
        low = re.sub(r"[^a-z]", "", w.lower())
        if low.endswith(("ing", "ed")) and lex.noun_classes(low):
            nxt = re.sub(r"[^a-z]", "", words[i + 1].lower()) if i + 1 < len(words) else ""
            pair = lex.noun_classes(f"{low} {nxt}") if nxt else []
            compound = len(pair) == 1 and pair != lex.noun_classes(low)
            if not compound and not (keep_verbs and lex.verb_class(low)):
                continue
        out.append(w)
    return " ".join(out)


def _trigger(toks: list[str], lex: Lexicon):
    """The action a "what next" question starts from: the clause after after / once / when /
    following, else the first action it names."""
    joined = " ".join(t for t in toks if not (t in _WH - {"when"} or re.fullmatch(r"p\d+", t) or t in _USUAL
                                              or t in {"ever", "next", "then", "subsequently", "afterwards"}))
    for marker in ("after", "once", "when", "following", "finish", "finishing"):
        m = re.search(rf"\b{marker}\b(.*)", joined)
        if m:
            for c in lex.parse(m.group(1)):
                if c.verb:
                    return c
    return next((c for c in lex.parse(joined) if c.verb), None)


def _general(q: OpenQuestion, toks: list[str], words: set[str]) -> bool:
    """General knowledge: nothing about a person's own doings. A question that neither names nor
    refers to the person is read as about memory only when it asks a memory's kind of thing (where
    something is kept, when or how often it happened) of a subject made only of kitchen classes."""
    if q.kind == "general":
        return True
    if q.about_person or q.videos:
        return False
    if not q.has_subject:
        return True
    if q.unknown:
        return True
    if q.kind == "count" and not (words & {"time", "times", "often"}):
        return True  # "how many teaspoons in a tablespoon?"
    if q.kind == "time" and q.order == "usual":
        return True  # "when was the telephone invented?" (memory is asked for the last or first time)
    if q.kind == "place" and not words & _KEEP_WORDS:
        return True  # "where do bananas grow?" (memory is asked where something is kept or was put)
    # a yes/no, a habit, a routine or "what ... X" asked of nobody in particular is general
    # ("is a tomato a fruit?", "how is bread made?"); where something is kept, when or how
    # many times something happened, the state at a time, stay memory's questions
    return q.kind not in ("place", "time", "count", "state", "activity")

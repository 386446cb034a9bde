"""Questions in words read into the typed `Query`, part by part.

    from memora_graph.agent.query import parse
    parse("What was the last thing I did in P09_105?", lex).brief()
    # list scope={"videos":["P09_105"]} selector=last

Each part is read on its own and the parts are combined; no pattern belongs to one kind of
question:

- scope      video ids ("in P06_101"), a time ("at 01:00", "between 1:00 and 2:30", "in the first 5
             minutes"), a session ("in my last video", "in the third session"), and an event the
             question's own action sits before or after ("where did I put the knife after I cut the onion")
- relation   "before / just before / prior to", "after / once / following", "while / during",
             "instead of / rather than" with the clause they introduce: the anchor event. When the
             rest of the question names no action of its own ("what do I usually do before I put the
             pot"), the relation is the question (previous / next / while / instead of); when it
             does, the clause scopes it
- selector   first / last / the nth / usually / all
- operation  the question's head: where, when, which video, how many, yes/no, what (did I do),
             how long, what state, how (steps), what next / before
- subject    the action and objects (`lexical`: EPIC classes, the question's words kept)

The whole reading is linear in the question's length; a question longer than `MAX_QUESTION`
characters, or an empty one, is refused with `QuestionError`.
"""

from __future__ import annotations

import re

from memora_graph.agent.query.lexical import (
    FUNCTION_WORDS, PERSON_WORDS, SCAFFOLD_WORDS, OpenQuestion, parse_open, seconds_in,
)
from memora_graph.agent.query.model import MAX_QUESTION, Action, Query, Scope, Subject
from memora_graph.errors import MemoraError
from memora_graph.perceive.lexicon import Lexicon


class QuestionError(MemoraError, ValueError):
    """A question that cannot be read: empty, or longer than MAX_QUESTION characters."""


_VIDEO = re.compile(r"\bP\d{2}_\d{2,3}\b", re.I)
_CLOCK = r"(\d{1,2}:\d{2}(?::\d{2}(?:\.\d+)?)?|\d+(?:\.\d+)?\s*(?:seconds?|secs?|s|minutes?|mins?)\b)"
_BETWEEN = re.compile(rf"\bbetween\s+{_CLOCK}\s+and\s+{_CLOCK}", re.I)
_FROM_TO = re.compile(rf"\bfrom\s+{_CLOCK}\s+(?:to|until|till)\s+{_CLOCK}", re.I)
_AT = re.compile(rf"\b(at|by|around|before|after|until|till|since)\s+(?:the\s+)?{_CLOCK}", re.I)
_FIRST_N = re.compile(r"\b(?:in|during|within)\s+the\s+(first|last|final)\s+(\d+(?:\.\d+)?|one|two|three|four|five|"
                      r"ten|few)\s+(seconds?|minutes?|mins?|secs?)\b", re.I)
_ORDINALS = {"first": 1, "second": 2, "third": 3, "fourth": 4, "fifth": 5, "sixth": 6, "seventh": 7, "eighth": 8,
             "ninth": 9, "tenth": 10, "1st": 1, "2nd": 2, "3rd": 3, "4th": 4, "5th": 5}
_SESSION_WORDS = r"(?:video|session|recording|clip|episode|day)"
_SESSION = re.compile(rf"\b(?:in|during|on|from)\s+(?:my|the|their|his|her|P\d{{2}}'s)\s+(?:very\s+)?"
                      rf"(first|last|latest|final|most recent|previous|{'|'.join(_ORDINALS)})\s+{_SESSION_WORDS}\b", re.I)
_NTH_TIME = re.compile(rf"\bthe\s+({'|'.join(k for k in _ORDINALS if k != 'first')})\s+time\b", re.I)
_NUMBERS = {"one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "ten": 10, "few": 3}
# relation markers and the relation they read as
_MARKERS = re.compile(r"\b(just before|right before|shortly before|immediately before|prior to|before|preceding|"
                      r"just after|right after|straight after|immediately after|shortly after|after|once|following|"
                      r"while|whilst|during|instead of|rather than|in place of)\b", re.I)
_RELATION = {"before": "before", "prior to": "before", "preceding": "before", "after": "after", "once": "after",
             "following": "after", "while": "while", "whilst": "while", "during": "while", "instead of": "instead_of",
             "rather than": "instead_of", "in place of": "instead_of"}
_ASKS_ACTION = re.compile(r"\b(what|which)\b(?:\s+\w+){0,4}?\s+(do|does|did|doing|done|happen|happens|happened|"
                          r"comes?|came|use|uses|used|thing|things|action|actions|step)\b", re.I)
_LAST_THING = re.compile(r"\b(first|last|final|latest|earliest)\s+(thing|things|action|step|event)s?\b", re.I)
_HOW_LONG = re.compile(r"\bhow\s+(long|much time)\b", re.I)
_OWNER = re.compile(r"\b(i|me|my|mine|myself|we|our|us)\b", re.I)


def check(question: str) -> str:
    """The question, stripped; QuestionError when it is empty or too long."""
    if not isinstance(question, str) or not question.strip():
        raise QuestionError("empty question: ask something (e.g. 'Where did I last put the knife?')")
    if len(question) > MAX_QUESTION:
        raise QuestionError(f"question too long: {len(question):,} characters (at most {MAX_QUESTION:,}); "
                            "ask one thing at a time, or pass a typed query (`recall`)")
    return question.strip()


def _clock(text: str) -> float | None:
    return seconds_in(text)


_VIDEO_PHRASE = re.compile(r"(?:\b(?:in|during|from|of|on|within|throughout|for)\s+)?(?:the\s+)?(?:(?:video|recording|"
                           r"session|clip|footage|episode)\s+)?\bP\d{2}_\d{2,3}\b(?:'s)?", re.I)


def _scope(text: str) -> tuple[Scope, str]:
    """The scope phrases of a question, and the question without them (with their prepositions:
    "put the lid in P01_105" is no "put in")."""
    videos = list(dict.fromkeys(v.upper() for v in _VIDEO.findall(text)))
    start = end = at = None
    session = None
    rest = _VIDEO_PHRASE.sub(" ", text)
    m = _BETWEEN.search(rest) or _FROM_TO.search(rest)
    if m:
        start, end = _clock(m.group(1)), _clock(m.group(2))
        rest = rest[:m.start()] + " " + rest[m.end():]
    m = _FIRST_N.search(rest)
    if m:
        n = float(_NUMBERS.get(m.group(2).lower(), 0) or m.group(2)) if not m.group(2).isdigit() else float(m.group(2))
        n *= 60 if m.group(3).lower().startswith("m") else 1
        if m.group(1).lower() == "first":
            start, end = 0.0, n
        rest = rest[:m.start()] + " " + rest[m.end():]
    m = _AT.search(rest)
    if m and start is None and end is None and m.group(2) and _clock(m.group(2)) is not None:
        t = _clock(m.group(2))
        word = m.group(1).lower()
        if word in ("after", "since"):
            start = t
        elif word in ("before", "until", "till", "by"):
            end = t
        else:  # "at 01:00": what holds at that moment
            at = t
        rest = rest[:m.start()] + " " + rest[m.end():]
    m = _SESSION.search(rest)
    if m and not videos and not re.search(r"\b(which|what)\s+" + _SESSION_WORDS, rest, re.I):
        w = m.group(1).lower()
        session = -1 if w in ("last", "latest", "final", "most recent", "previous") else _ORDINALS.get(w)
        rest = rest[:m.start()] + " " + rest[m.end():]
    return Scope(videos=videos, start=start, end=end, at=at, session=session), rest


def _anchor(text: str, lex: Lexicon) -> tuple[str | None, Action | None, str]:
    """A relation marker and the event its clause names; the question without that clause."""
    for m in _MARKERS.finditer(text):
        word = m.group(1).lower()
        rel = _RELATION[word.split()[-1] if word.split()[-1] in _RELATION else word]
        if word.startswith(("instead", "rather", "in place")):
            rel = "instead_of"
        clause = text[m.end():]
        cut = re.search(r"[,?;.]|\b(what|where|which|how|when)\b", clause, re.I)
        tail = ""
        if cut:
            tail, clause = clause[cut.start():], clause[:cut.start()]
        if not clause.strip():
            continue
        reading = parse_open(f"did they {clause.strip()}", lex)
        act = Action(verb=reading.verb, objects=list(reading.nouns), words=_words(clause, reading, lex))
        if act.empty():
            continue
        return rel, act, (text[:m.start()] + " " + tail).strip()
    return None, None, text


def _words(text: str, reading: OpenQuestion, lex: Lexicon) -> list[str]:
    """The question's own words for its objects (kept so answers and vocabulary use them)."""
    out = []
    prev = ""
    for tok in re.findall(r"[A-Za-z][A-Za-z0-9]*", text):
        low = tok.lower()
        before, prev = prev, low
        if re.fullmatch(r"p\d+", low) or low in FUNCTION_WORDS or low in PERSON_WORDS:
            continue
        if lex.noun_classes(low) and not lex.verb_class(low):
            out.append(low)
        elif low not in lex.known and low not in SCAFFOLD_WORDS and (before in _DETERMINERS or not low.isalpha()):
            out.append(low)  # a name no class knows, where a noun goes: "the v60", "my aeropress"
    return list(dict.fromkeys(out))


_DETERMINERS = frozenset("the a an my our your their his her this that these those some any".split())


_OPERATION = {"time": "when", "count": "count", "place": "where", "yesno": "exists", "state": "state", "activity": "list",
              "next": "next", "routine": "steps", "actions": "list", "general": "list"}


_ELLIPSIS = re.compile(r"^\s*(?:and|what about|how about|and what about|and how about|same for|now)\b", re.I)
_LEFT = re.compile(r"\b(and|what|how|about|same|for|now|then|the|in|on|during|video|recording|session|please)\b|[^\w]",
                   re.I)


def _ellipsis(text: str, lex: Lexicon) -> Query | None:
    """"How many times did I open the fridge in P01_102? And in P01_103?": the last sentence only
    changes the scope, so the question is the one before it with that scope."""
    parts = [p.strip() for p in re.findall(r"[^.?!]+[.?!]?", text) if p.strip(" .?!")]
    if len(parts) < 2 or not _ELLIPSIS.match(parts[-1]):
        return None
    scope, rest = _scope(parts[-1])
    if scope.empty() or _LEFT.sub("", rest).strip():
        return None
    prev = parse(" ".join(parts[:-1]), lex)
    return prev.model_copy(update={"scope": scope.model_copy(update={"after": prev.scope.after,
                                                                     "before": prev.scope.before}), "text": text})


def parse(question: str, lex: Lexicon | None = None) -> Query:
    """The question as a typed `Query` (see the module docstring)."""
    text = check(question)
    lex = lex or Lexicon.load()
    follow = _ellipsis(text, lex)
    if follow is not None:
        return follow
    scope, rest = _scope(text)
    rel, anchor, main = _anchor(rest, lex)
    # the question less its scope phrases: its head, person, action and objects, unknown words
    base = parse_open(re.sub(r"\s+", " ", rest).strip(), lex)
    body = parse_open(main, lex) if anchor is not None else base
    own = bool(body.verbs or body.nouns) and not (body.kind == "next")
    asks_action = bool(_ASKS_ACTION.search(main)) or body.kind in ("actions", "next", "routine", "activity")
    kind = base.asked if base.kind == "general" and base.asked and _scoped(scope) else base.kind
    op = _OPERATION[kind]
    if kind == "time":
        op = "which_video" if re.search(r"\b(which|what)\s+(\w+\s+){0,2}(videos?|recordings?|sessions?|clips?|footage)\b|"
                                        r"name the video", text, re.I) else "when"
    if _HOW_LONG.search(text):
        op = "duration"
    selector = _selector(rest)
    nth = None
    m = _NTH_TIME.search(text)
    if m:
        selector, nth = "nth", _ORDINALS[m.group(1).lower()]
    m = _LAST_THING.search(text)
    relation = None
    if anchor is not None:
        if own and not (asks_action and not body.nouns and body.verb in (None, "use")):
            # the question's own action, scoped by the event ("where did I put the knife after I cut the onion")
            scope = scope.model_copy(update={"after" if rel in ("after",) else "before": anchor}) \
                if rel in ("before", "after") else scope
            relation = "while" if rel == "while" else None
            if rel == "instead_of":
                relation = "instead_of"
        else:
            relation = rel
        if relation is not None and op in ("list", "steps", "next", "exists") and rel in ("before", "after"):
            op = "previous" if rel == "before" else "next"
            relation = rel
    elif base.kind == "next":
        relation = "after"
        anchor = Action(verb=base.verb, objects=list(base.nouns), words=_words(text, base, lex))
    scoped = _scoped(scope)
    if scoped and base.kind in ("general", "actions", "routine", "activity") and not (base.verbs or base.nouns) \
            and anchor is None and op not in ("duration",):
        op = "list"  # "what happened in P30_107", "what did I do first in my third session"
    if m and op in ("list", "next", "steps", "exists") and anchor is None:
        op, selector = "list", m.group(1).lower().replace("final", "last").replace("latest", "last").replace(
            "earliest", "first")
    if op == "list" and selector == "usual" and (scope.videos or scope.start is not None or scope.at is not None or scope.session) and \
            not (body.verbs or body.nouns):
        selector = "all"  # "what happened in P30_107": the video's log
    if op in ("count", "exists", "duration") and selector in ("first", "last"):
        selector = "usual"
    if op == "state" and selector == "usual":
        selector = "last"
    subj_reading = body if anchor is not None else base
    if (relation in ("after", "before") and op in ("next", "previous")) or (anchor is not None and not own):
        subj = Subject()
    else:
        nouns = [n for n in subj_reading.nouns if n != subj_reading.place] or list(subj_reading.nouns)
        goal, light = _goal(text) if op == "steps" else ("", False)
        subj = Subject(verb=None if light else subj_reading.verb, objects=nouns,
                       words=_words(main if anchor else text, subj_reading, lex), place=subj_reading.place,
                       source=subj_reading.source, goal=goal)
    if op == "next" and anchor is None:
        anchor = Action(verb=base.verb, objects=list(base.nouns))
        relation = "after"
    person = base.persons[0] if base.persons else None
    world = base.kind == "general" and not scoped
    if world and _memory_anyway(text, base, scope):
        world = False
        op = _OPERATION.get(_rekind(text, base), op)
        if op == "state" and selector == "usual":
            selector = "last"
    if op == "where" and selector == "usual" and _WHERE_NOW.match(text) and not _KEPT.search(text):
        selector = "last"  # "where are the plates?": where they are now, not where they usually go
    return Query(operation=op, subject=subj, scope=scope, selector=selector, nth=nth, relation=relation,
                 anchor=anchor if relation else None, unit="videos" if base.unit == "videos" else "times",
                 person=person, world=world, unknown=list(base.unknown), text=text)


_LIGHT = re.compile(r"\b(make|makes|making|made|prepare|prepares|preparing|prepared|do|does|doing|cook|cooks|"
                    r"cooking|get|gets|go about|set up|sets up)\b\s+(?:a |an |the |some |my |their |his |her |your )?"
                    r"([a-z][a-z0-9 ]{1,40}?)\s*(?:[?.!,]|$|\bin\b|\bat\b|\bon\b|\bfor\b|\bwith\b)", re.I)


_FIRST_WORDS = re.compile(r"\b(first|earliest|initially|originally|to begin|to start|at the start|at the beginning)\b", re.I)
_LAST_WORDS = re.compile(r"\b(last|latest|most recent|most recently|final|finally|lately|previous|now|currently|at the "
                         r"end)\b", re.I)
_USUAL_WORDS = re.compile(r"\b(usually|typically|normally|generally|often|always|tends?|habitually|regularly|commonly|"
                          r"mostly|usual|customarily|routinely)\b", re.I)


_WHERE_NOW = re.compile(r"\s*where\s+(is|are|'s)\b", re.I)
_KEPT = re.compile(r"\b(kept|keep|stored|store|go|goes|belong|belongs|live|lives|usually|normally|typically|generally|"
                   r"often|always|tend)\b", re.I)


def _scoped(scope: Scope) -> bool:
    return bool(scope.videos or scope.start is not None or scope.end is not None or scope.at is not None
                or scope.session is not None)


def _selector(text: str) -> str:
    """first | last | usual, from the question's own words (nth is read apart)."""
    last = _LAST_WORDS.search(text)
    first = _FIRST_WORDS.search(text)
    if _USUAL_WORDS.search(text) and not (first or last):
        return "usual"
    if first and last:
        return "first" if first.start() > last.start() else "last"
    return "first" if first else "last" if last else "usual"


def _goal(text: str) -> tuple[str, bool]:
    """The goal of a steps question in words ("make tea"), and whether its verb is a light one
    (make, prepare, do, get: the goal is named by its object, not by that verb's class)."""
    found = [m for i in range(len(text)) if text[i].isalpha() and (i == 0 or not text[i - 1].isalpha())
             for m in [_LIGHT.match(text, i)] if m is not None]
    found = [m for m in found if m.group(1).lower() not in ("do", "does", "doing")] or \
        [m for m in found if not re.match(r"(i|you|we|they|he|she|p\d+)\b", m.group(2), re.I)]
    if not found:
        return "", False
    m = found[-1]
    verb = m.group(1).lower()
    base = {"makes": "make", "making": "make", "made": "make", "prepares": "prepare", "preparing": "prepare",
            "prepared": "prepare", "cooks": "cook", "cooking": "cook", "gets": "get", "sets up": "set up"}.get(verb, verb)
    return f"{base} {m.group(2).strip()}".strip(), base in ("make", "prepare", "do", "get", "set up", "go about")


def _rekind(text: str, base: OpenQuestion) -> str:
    """The kind of a question the word-level parser read as general knowledge but that names a
    definite thing of the owner's ("where is the kettle?", "is the fridge open now?")."""
    low = text.lower()
    if re.match(r"\s*where\b", low):
        return "place"
    if re.search(r"\b(open|closed|shut|on|off|empty|full|clean|dirty)\b", low) and re.match(r"\s*(is|are)\b", low):
        return "state"
    return base.kind if base.kind != "general" else "actions"


def _memory_anyway(text: str, base: OpenQuestion, scope: Scope) -> bool:
    """A question naming no person is about the memory's owner when it speaks of a definite thing
    of theirs ("the kettle", "my plates"), asks where it is or what state it is in, and names no
    word outside the kitchen's classes; a question about kinds of things stays the world's."""
    if base.unknown or not base.nouns or base.persons:
        return False
    low = text.lower()
    if _OWNER.search(low):
        return True
    definite = re.search(r"\b(the|my|our)\s+\w+", low)
    if not definite:
        return False
    return bool(re.match(r"\s*(where|is|are|was|were)\b", low)) and not re.search(
        r"\b(is|are)\s+(a|an)\s+\w+\s+(a|an)\b|\bmade of\b|\binvented\b|\bgrow\b", low)

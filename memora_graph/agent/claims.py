"""Options as claims about how a task is done, checked against the task-pattern records.

An EAM-QA option about a routine or a method is often a claim about how a task is organised:
the order of two steps ("empties it out before washing"), a staging place ("sets it aside on the
counter, returns to it later"), batching ("retrieves one utensil as needed" against "lays out a
set first"), repetition ("alternates stretching and folding"), setup ("opens the containers
before filling them"), the carrier of a transfer ("scoops it with a spoon") or closing what was
opened ("closes the cupboard after use" against "leaves it open"). Consolidation
writes one record per pattern found (`consolidate.patterns`); `evidence` turns each into a
`Claim`. Here every option is read for the claims it makes, and each pattern record about the
question's subject *supports* it (+), *contradicts* it (-) or does not speak to it (0), weighted
by the record's share of held occurrences (n of m).

Deterministic; the cues are word lists of how such claims are phrased, not question wordings.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

from memora_graph.consolidate import vocab
from memora_graph.consolidate.task_records import PREFERENCE_FAMILIES
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.results import PreferenceRecord, RoutineRecord

ENV = "MEMORA_TASK_CLAIMS"  # "off": the offline reader does not re-rank options with the claims (on by default)


def enabled() -> bool:
    """Whether the offline reader re-ranks options with the task-pattern claims. On by default since
    issue 33's third round: scoped to options about the records' objects and read with the
    narrated verb words, they lift MEMORA's EAM-QA on the development participants (P01-P03:
    61.3 -> 62.2, SRoutine 46.1 -> 48.7, no type lower) and leave the held-out one as it was
    (P04: 61.6 both, 2 answers gained and 2 lost), where the earlier rounds lowered it by one
    answer. `MEMORA_TASK_CLAIMS=off` reads as before them."""
    return os.environ.get(ENV, "on").lower() not in ("0", "off", "false", "no")


def is_task_record(rec) -> bool:
    """A record of the task memory (consolidate/tasks.py, consolidate/patterns/): a recurring task's
    stages (a routine of kind "task_routine") or how tasks are done (a preference whose subtype is a
    pattern family). The offline reader reads them as claims (`enabled()`, on by default); a
    person's own goal is planned from their tasks (`planner.plan`), the benchmark's policy composes
    (`planner.TASK_FIRST`)."""
    return ((isinstance(rec, RoutineRecord) and rec.kind == "task_routine")
            or (isinstance(rec, PreferenceRecord) and rec.subtype in PREFERENCE_FAMILIES))


WEIGHT = 0.6  # what one fully held pattern record adds to (or takes from) an option's score
MAX_SHIFT = 1.2  # the most the records move one option
CARRYING = frozenset({"retrieve", "leave", "transition"})  # verb categories of taking, putting down, moving
USUAL = 0.5  # a staging record speaks only when the object was staged in at least this share of its tasks

_CUES = {
    "one": r"\bone at a time\b|\bas needed\b|\bas (?:the )?(?:task|recipe|step)s? requires?\b|\bone by one\b|"
           r"\bindividually\b|\bfor the next\b|\beach (?:one|item|time)\b|\bone needed\b|\bsingle (?:item|utensil|one)\b",
    "batch": r"\ball (?:of )?(?:the|them|items|utensils|containers)\b|\b(?:a|the|broad|full|whole) (?:\w+ )?set\b|"
             r"\btogether\b|\bseveral\b|\bgathers?\b|\bcollects?\b|\blays? out\b|\bpile\b|\bin bulk\b|\bbatch\b|"
             r"\bat once\b|\beverything\b|\bhandful\b|\bboth\b|\bthem all\b|\ball (?:later|afterward|together)\b",
    "repeat": r"\balternat\w*\b|\brepeat\w*\b|\bagain\b|\bpasses\b|\bback and forth\b|\bcycles?\b|\banother pass\b|"
              r"\bseveral times\b|\bbetween \w+ing\b",
    # a portion at a time, coming back for the next: one at a time and repeated passes at once
    "more": r"\breturn(?:s|ing)? (?:\w+ ){0,4}for (?:more|another|the next|a second)\b|\b(?:reaches|goes|comes) back for\b|"
            r"\breaches for (?:another|the next)\b|\b(?:takes|adds|grabs) another\b|\bbefore taking another\b|"
            r"\banother (?:scoop|portion|piece|pass|handful|spoonful|round|batch|slice|wash|one)\b|\bin portions\b|"
            r"\b(piece|slice|bit|item|spoonful|scoop|handful) by \1\b|\bbetween additions\b|\bgradually\b|\bprogressively\b",
    "once": r"\bonce\b|\bsingle\b|\bone continuous\b|\bwithout stopping\b|\bin one go\b|\bone (?:firm )?motion\b",
    "staging": r"\bholding spot\b|\bstag(?:e|es|ed|ing)\b|\blanding\b|\breturns? (?:to|for) (?:it|them)\b|"
               r"\bretrieves? (?:it|them)\b|\bpicks? (?:it|them) up again\b|\bcomes? back (?:to|for)\b|\btemporar\w+\b",
    "direct": r"\bdirectly\b|\bstraight\b",
    "first": r"\bfirst\b|\bbefore\b|\bsets? up\b|\bprepares?\b|\bready\b",
    # closing what was opened, or leaving it open
    "close": r"\bclos(?:e|es|ed|ing)\b|\bshut\w*\b|\breseal\w*\b|\brecap\w*\b|\b(?:lid|cap) back\b",
    "open_left": r"\b(?:leaves?|leaving|left|keeps?|keeping)\b(?:\s+[\w-]+){0,4}?\s+(?:open|ajar|uncapped|unsealed|uncovered)\b|"
                 r"\buncapped\b|\bunsealed\b|\bopen (?:until|while|throughout)\b",
}
_CUE = {k: re.compile(v) for k, v in _CUES.items()}


@dataclass(frozen=True)
class Claim:
    """A pattern record as the reader checks options against it."""

    family: str  # order | staging | batch | repetition | setup | carrier | closure
    way: str  # batch: one_at_a_time | batch; repetition: alternate | repeat; closure: closes | leaves_open; else ""
    verbs: tuple[str | None, ...]  # the record's actions, in its order (verb classes)
    nouns: tuple[str, ...]  # the object classes it is about
    share: float  # n of m
    ids: tuple[str, ...]


def cues(option: str) -> set[str]:
    low = option.lower()
    return {k for k, rx in _CUE.items() if rx.search(low)}


def _about(claim: Claim, subject: set[str]) -> bool:
    """The record is about one of the question's objects (at class or head level)."""
    return bool(subject & set(claim.nouns)) or \
        bool({n.split(":")[0] for n in subject} & {n.split(":")[0] for n in claim.nouns})


def _verb_at(clauses, verb: str | None, lex: Lexicon, exact: bool = False) -> int | None:
    """The first clause doing `verb` (its class; or any verb of its category unless `exact`)."""
    for i, c in enumerate(clauses):
        if c.verb and verb and (c.verb == verb or (not exact and lex.same_category(c.verb, verb))):
            return i
    return None


GENERAL = frozenset({"utensil", "container", "cutlery", "food", "vegetable", "fruit", "drink"})  # name a kind, not a thing
BOOKKEEPING = vocab.TAKING | vocab.RELEASING | {"hold", "move"}  # verbs that frame every task: they say nothing of its method


def _named_objects(option: str, lex: Lexicon) -> set[str]:
    """The particular objects an option names (not a word for a whole kind)."""
    return {n for c in lex.parse(option) if not c.negated for n in c.objects() if n not in GENERAL}


def _on_claim(option: str, claim: Claim, lex: Lexicon) -> bool:
    """The option is about the record's objects: it names one of them (at class or head level), or
    names no particular object ("sets it aside": the question's subject; "a utensil", "the food": a
    word for a whole category)."""
    named = _named_objects(option, lex)
    return not named or _about(claim, named)


def _ordered(option: str, lex: Lexicon):
    """The option's actions in the order it says they happen (the clause parser already reads
    "X after Y" as Y, then X)."""
    return [c for c in lex.parse(option) if not c.negated and c.verb]


def verdict(claim: Claim, option: str, cue: set[str], lex: Lexicon) -> float:
    """+1 the record supports the option, -1 it contradicts it, 0 it does not speak to it."""
    f = claim.family
    if "more" in cue:  # "adds some, then returns for more": a portion at a time, not a set laid out first
        cue = (cue - {"batch"}) | {"one", "repeat"}
    if f in ("batch", "staging", "carrier") and not _on_claim(option, claim, lex):
        return 0.0  # an option about other objects ("collects all the waste") is not spoken to
    if f == "batch":  # about fetching and carrying: it speaks to an option that takes, puts or moves things
        if "more" not in cue and not any(lex.verb_category.get(c.verb) in CARRYING for c in _ordered(option, lex)):
            return 0.0
        want = "one" if claim.way == "one_at_a_time" else "batch"
        other = "batch" if want == "one" else "one"
        return (want in cue) - (other in cue) if (want in cue) != (other in cue) else 0.0
    if f == "repetition":
        if "repeat" in cue:
            clauses = _ordered(option, lex)
            hits = sum(_verb_at(clauses, v, lex) is not None for v in claim.verbs)
            return 1.0 if hits else 0.5
        return -0.5 if "once" in cue else 0.0
    if f == "staging":  # only the person's usual way speaks: staged in most of the tasks with the object
        return 1.0 if "staging" in cue and claim.share >= USUAL else 0.0
    if f == "order" and len(claim.verbs) == 2:
        clauses = _ordered(option, lex)  # the record's two actions themselves, not any of their kind
        i, j = _verb_at(clauses, claim.verbs[0], lex, exact=True), _verb_at(clauses, claim.verbs[1], lex, exact=True)
        if i is None or j is None or i == j:
            return 0.0
        return 1.0 if i < j else -1.0
    if f == "setup":  # the option's first action is one the record sets up first, on the same object
        clauses = _ordered(option, lex)
        if "first" in cue and clauses and set(clauses[0].nouns) & set(claim.nouns) and \
                any(_verb_at(clauses[:1], v, lex, exact=True) is not None for v in claim.verbs if v not in BOOKKEEPING):
            return 1.0
        return 0.0
    if f == "closure":  # closes what it opened, or leaves it open: an option about the same object
        if not _on_claim(option, claim, lex) or ("close" in cue) == ("open_left" in cue):
            return 0.0
        says_closed = "close" in cue
        return 1.0 if says_closed == (claim.way == "closes") else -1.0
    if f == "carrier":  # the option names the tool that carried it ("directly" records say too little)
        if claim.way == "directly" or len(claim.nouns) < 2:
            return 0.0
        clauses = _ordered(option, lex)  # the same transfer (its action), carried by the tool it names
        if not any(_verb_at(clauses, v, lex) is not None for v in claim.verbs):
            return 0.0
        opt_nouns = {n for c in clauses for n in c.nouns}
        return 1.0 if opt_nouns & set(claim.nouns[1:]) else 0.0
    return 0.0


def adjust(choices: list[str], claims: list[Claim], subject: set[str], lex: Lexicon) -> tuple[list[float], list[list[str]]]:
    """Per option, how much the pattern records about the subject move its score, and their ids."""
    shifts, ids = [0.0] * len(choices), [[] for _ in choices]
    # a closure record speaks to the options that name its object, whatever the question calls it
    # ("upper storage": the options say which cupboard)
    about = [(c, on) for c in claims if (on := _about(c, subject)) or c.family == "closure"]
    if not about:
        return shifts, ids
    for k, option in enumerate(choices):
        cue = cues(option)
        named = _named_objects(option, lex) if not all(on for _, on in about) else set()
        for c, on_subject in about:
            if not on_subject and not _about(c, named):
                continue
            v = verdict(c, option, cue, lex)
            if v:
                shifts[k] += WEIGHT * v * c.share
                if v > 0:
                    ids[k] += list(c.ids[:3])
        shifts[k] = max(-MAX_SHIFT, min(MAX_SHIFT, shifts[k]))
    # a record that speaks the same way to every option tells them apart no better
    if len(set(round(s, 6) for s in shifts)) == 1:
        return [0.0] * len(choices), [[] for _ in choices]
    return shifts, ids

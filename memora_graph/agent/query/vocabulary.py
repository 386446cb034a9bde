"""A person's own words: every surface name their narrations use, tied to its class and evidence.

    vocab = Vocabulary.of(view, lex)
    vocab.resolve("v60")        # Resolved(word='v60', how='exact', classes=[...], count=52)
    vocab.resolve("chpping")    # how='fuzzy', word='chopping'
    vocab.resolve("wok")        # how='class' (no narration of theirs says wok; the pan class does)
    vocab.name("sausage")       # 'chorizo', when that is what they call it

A subject word resolves exact (a word of theirs), then fuzzy (a misspelling of one of their words,
difflib), then by class (the lexicon's class of the word: the answer then says that it widened).
Answers name classes in the person's most used word for them (`name`).
"""

from __future__ import annotations

import difflib
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from memora_graph.agent.query import wordings
from memora_graph.agent.query.wordings import WORD
from memora_graph.perceive.lexicon import Lexicon

FUZZY_CUTOFF = 0.8


@dataclass
class Resolved:
    word: str  # the word as the person says it (corrected when fuzzy)
    how: str  # exact | fuzzy | class | unknown
    classes: list[str] = field(default_factory=list)
    count: int = 0  # narrated steps that say the word
    asked: str = ""  # the word as asked


@dataclass
class Vocabulary:
    words: Counter  # word (and two-word name) -> narrated steps that say it
    names: dict[str, Counter]  # class -> Counter of the surface names that read as it
    segments: dict[str, list[str]]  # word -> the segments that say it (first 20)

    @classmethod
    def of(cls, view, lex: Lexicon, log=None) -> Vocabulary:
        """The vocabulary of the person `view` holds, cached on the view. A live view's log grows
        by the segments remembered since (retrieve/steps.py, `StepRows.added`: they come after
        the segments read); only their steps are added, not the whole log read again."""
        from memora_graph.agent.query.log import action_log

        log = action_log(view, lex) if log is None else log
        rows = log.rows
        known = view.__dict__
        cached = known.get("_query_vocabulary")
        read = known.get("_query_vocab_read")  # (the rows' lineage, segments read)
        wordings.seed(view, lex)
        seen = known.setdefault(wordings.TEXT_WORDS, {})
        if cached is not None and read is not None and read[0] is rows.lineage and len(rows.segments) >= read[1]:
            if len(rows.segments) > read[1]:  # the same log, grown by remembered segments: only theirs are read
                new = np.flatnonzero(rows.segment >= read[1])
                cached._add(log, new[np.argsort(rows.segment[new], kind="stable")], lex, seen)
                known["_query_vocab_read"] = (rows.lineage, len(rows.segments))
                wordings.keep(view, lex)
            return cached
        vocab = cls(Counter(), {}, {})
        vocab._add(log, np.arange(len(rows)), lex, seen)
        known["_query_vocabulary"] = vocab
        known["_query_vocab_read"] = (rows.lineage, len(rows.segments))
        wordings.keep(view, lex)  # saved for the next process (query/wordings.py)
        return vocab

    def _add(self, log, at: np.ndarray, lex: Lexicon, seen: dict) -> None:
        """Count the words and names of the narrated steps at positions `at` of `log` (a
        `StepLog`; `seen` keeps each wording's reading), as a walk of the steps in that order
        would: the counts per wording (taken in the order of their first step, so that every
        word and name is first met where that walk meets it), the segments (first 20 a word)
        by a walk of only the steps whose wording has a word still short of them."""
        rows, classes = log.rows, log.classes
        at = np.asarray(at, dtype=np.int64)
        if not len(at):
            return
        word = rows.word[at]
        present, first = np.unique(word, return_index=True)
        counts = np.bincount(word, minlength=len(rows.words))
        parsed_of: dict[int, list] = {}
        for w in present[np.argsort(first, kind="stable")].tolist():
            text = rows.words[w][3].lower()
            parsed = seen.get(text)
            if parsed is None:
                parsed = seen[text] = _phrases(lex, WORD.findall(text))
            parsed_of[w] = parsed
            nouns, n = classes[w][2], int(counts[w])
            for w_, c in parsed:
                if c is None or " " in w_:
                    self.words[w_] += n
                self.segments.setdefault(w_, [])
                if c is not None and c in nouns:
                    self.names.setdefault(c, Counter())[w_] += n
        full = {w: False for w in parsed_of}
        segments, ids = self.segments, rows.segments
        for w, sg in zip(word.tolist(), rows.segment[at].tolist()):
            if full[w]:
                continue
            segment, done = ids[sg], True
            for w_, _ in parsed_of[w]:
                segs = segments[w_]
                if len(segs) < 20 and (not segs or segs[-1] != segment):
                    segs.append(segment)
                done = done and len(segs) >= 20
            full[w] = done

    def says(self, word: str) -> int:
        return self.words.get(word.lower(), 0)

    def resolve(self, word: str, lex: Lexicon) -> Resolved:
        w = word.lower().strip()
        forms = [w, *(x for x in lex.lemmas(w) if x != w)]
        if w.endswith("s") and len(w) > 3:
            forms.append(w[:-1])
        for f in forms:
            if self.words.get(f):
                return Resolved(f, "exact", lex.noun_classes(f), self.words[f], word)
        if len(w) >= 4 and " " not in w:
            close = difflib.get_close_matches(w, [k for k in self.words if " " not in k and len(k) >= 3], n=1,
                                              cutoff=FUZZY_CUTOFF)
            if close:
                return Resolved(close[0], "fuzzy", lex.noun_classes(close[0]), self.words[close[0]], word)
        classes = lex.noun_classes(w)
        if classes:
            return Resolved(w, "class", classes, 0, word)
        if len(w) >= 4 and " " not in w:  # a misspelling of a word the lexicon knows ("chpping" -> chopping)
            close = difflib.get_close_matches(w, sorted(lex.known), n=1, cutoff=FUZZY_CUTOFF)
            if close:
                return Resolved(close[0], "fuzzy", lex.noun_classes(close[0]), self.words.get(close[0], 0), word)
        return Resolved(w, "unknown", [], 0, word)

    def name(self, noun: str) -> str | None:
        """The person's most used word for a class (None when they never name it)."""
        c = self.names.get(noun)
        if not c:
            return None
        return c.most_common(1)[0][0]


def _phrases(lex: Lexicon, toks: list[str]) -> list[tuple[str, str | None]]:
    """Each word of a narration, and each name of a class in it, read as the lexicon's phrases,
    longest first ("drying rack", "washing up liquid" before "rack", "liquid"): (word or name, its
    class or None)."""
    out: list[tuple[str, str | None]] = [(w, None) for w in toks]
    lem = [(lex.lemmas(w) or [w])[0] for w in toks]
    i = 0
    while i < len(toks):
        for n in (3, 2, 1):
            c = lex.noun_phrases.get(tuple(lem[i:i + n])) if i + n <= len(toks) else None
            if c is None:
                continue
            if n > 1 and i == 0 and lex.verb_class(toks[i]) and lex.noun_phrases.get(tuple(lem[i + 1:i + n])) == c:
                continue  # "open drawer" is opening the drawer: the name is "drawer" ("drying rack" stays one)
            out.append((" ".join(toks[i:i + n]), c))
            i += n
            break
        else:
            i += 1
    return out


def _one(lex: Lexicon, text: str) -> str | None:
    got = lex.noun_classes(text)
    return got[0] if len(got) == 1 else None


def class_words(noun: str) -> set[str]:
    """The words of a class key ('board:chopping' -> {'board', 'chopping'})."""
    return {p for part in noun.replace("_", " ").split(":") for p in part.split() if p}

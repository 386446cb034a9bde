"""The reader's reading of every distinct step wording, kept with the persisted tool stores, so
that a new process's first `ask` does not read them all again (31,977 wordings at 1,000 h: 2-3
CPU-s of parsing).

What `action_log` (log.py: the step's verb, objects, nouns and place) and `Vocabulary.of`
(vocabulary.py: the words and class names of its text) read from a wording is a function of the
wording, the lexicon and this code alone. `seed` fills a view's per-wording tables (the ones
those two keep on the view) from the file saved for its participant (retrieve/derived.py); `keep`
saves them again once they hold a share (`SAVE_SHARE`) of wordings the file lacks: the first
`ask` after the stores were persisted, or after enough new wordings were remembered. The key is
the sha256 of the lexicon's tables and of the source of the modules that read them: another
lexicon or another version of the code makes the file stale, and it is read again from the
wordings (never trusted). Whatever the file holds, an answer is that of a reading from scratch
(tests/agent/test_query_wordings.py)."""

from __future__ import annotations

import hashlib
import json
import re
import sys
from pathlib import Path

from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve import derived

WORD = re.compile(r"[a-z][a-z0-9]*")  # the words of a step's text (vocabulary.py)
NAME = "query_wordings"
SAVE_SHARE = 0.01  # save again once this share of the wordings read is missing from the file
# the modules whose code reads a wording (any change to them makes a saved file stale)
READERS = ("memora_graph.perceive.lexicon", "memora_graph.agent.reading", "memora_graph.agent.query.lexical",
           "memora_graph.agent.query.log", "memora_graph.agent.query.vocabulary", __name__)

LOG_WORDS = "_open_log_words"  # (narration, object, action) -> (verb, objects, nouns, place): log.py
TEXT_WORDS = "_query_vocab_text"  # lowered text -> [(word or name, class or None)]: vocabulary.py
_SAVED = "_query_wordings_saved"  # (log wordings, texts) the file held or was saved with

_keys: dict[int, tuple[Lexicon, str]] = {}


def key(lex: Lexicon) -> str:
    """The sha256 of the lexicon's tables and of the reading code (once per lexicon a process)."""
    got = _keys.get(id(lex))
    if got is not None and got[0] is lex:
        return got[1]
    h = hashlib.sha256()
    for mod in READERS:
        __import__(mod)
        h.update(Path(sys.modules[mod].__file__).read_bytes())
    tables = [sorted(lex.known), [[list(k), v] for k, v in lex.verb_phrases.items()],
              [[list(k), v] for k, v in lex.noun_phrases.items()], lex.noun_category, lex.verb_category,
              lex.verb_keys, lex.noun_keys]
    h.update(json.dumps(tables, ensure_ascii=False, sort_keys=True).encode())
    _keys[id(lex)] = (lex, h.hexdigest())
    return _keys[id(lex)][1]


def seed(view, lex: Lexicon) -> None:
    """Fill the view's per-wording tables from the saved file (once per view)."""
    known = view.__dict__
    if _SAVED in known:
        return
    known[_SAVED] = (0, 0)
    data = derived.load(view, NAME, key(lex))
    if data is None:
        return
    try:
        words = {(n, o, a): (v, tuple(objs), tuple(nouns), place) for n, o, a, v, objs, nouns, place in data["log"]}
        # a text's words, then the names of classes in it (saved: only the names; `_phrases`)
        texts = {t: [(w, None) for w in WORD.findall(t)] + [(w, c) for w, c in names] for t, names in data["text"]}
    except (KeyError, TypeError, ValueError):
        derived.log.warning(f"{derived.FILENAME.format(name=NAME, participant=view.participant)}: damaged "
                            "(not the tables it should hold); not used, computed again")
        return
    for name, table in ((LOG_WORDS, words), (TEXT_WORDS, texts)):
        had = known.get(name)
        known[name] = table if not had else {**table, **had}  # (what the view read itself stands)
    known[_SAVED] = (len(words), len(texts))


def keep(view, lex: Lexicon) -> bool:
    """Save the view's per-wording tables when they hold a share of wordings the file lacks."""
    known = view.__dict__
    words, texts = known.get(LOG_WORDS) or {}, known.get(TEXT_WORDS) or {}
    had = known.get(_SAVED, (0, 0))
    new = len(words) - had[0] + len(texts) - had[1]
    if new <= 0 or new < SAVE_SHARE * (len(words) + len(texts)):
        return False
    payload = {"log": [[*k, v, list(objs), list(nouns), place] for k, (v, objs, nouns, place) in words.items()],
               "text": [[t, [[w, c] for w, c in p if c is not None or " " in w]] for t, p in texts.items()]}
    saved = derived.save(view, NAME, key(lex), payload)
    known[_SAVED] = (len(words), len(texts))  # saved, or not writable: not tried again for these
    return saved

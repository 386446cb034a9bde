"""The reader's per-wording classes kept with the persisted stores (agent/query/wordings.py,
retrieve/derived.py): a new process reads them instead of parsing every wording again, answers
as a reading from scratch does, and never trusts a stale or damaged file."""

from __future__ import annotations

import json
import shutil
from collections import Counter

import numpy as np
import pytest

from memora_graph.agent.query import recall, wordings
from memora_graph.agent.query import log as query_log
from memora_graph.agent.query import vocabulary as query_vocabulary
from memora_graph.agent.query.log import action_log
from memora_graph.agent.query.vocabulary import Vocabulary
from memora_graph.bank import Bank
from memora_graph.bank.derived import sha256_bytes
from memora_graph.integrity.verify import verify_bank
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve import MemoryView
from memora_graph.retrieve.view import persist_bank

P = "P37"


@pytest.fixture(scope="module")
def lex():
    return Lexicon.load()


@pytest.fixture()
def bank(small_bank, tmp_path):
    path = tmp_path / "bank"
    shutil.copytree(small_bank[0], path, ignore=shutil.ignore_patterns("tools-*", "derived-*", "manifest.json"))
    shutil.copy(small_bank[0] / "manifest.json", path)  # (copied: the fixture bank may hold records of derived files)
    persist_bank(path, [P])
    return path


def _file(bank):
    return bank / ".cache" / f"derived-{wordings.NAME}-{P}.json"


def _answers(bank, lex) -> list:
    """Answers of a fresh view (as a new process opens one) to queries over the whole log, with
    the vocabulary it read."""
    with MemoryView.open(bank, P) as view:
        log = list(action_log(view, lex))
        acts = [k for k, _ in Counter((s.verb, s.objects[0]) for s in log if s.verb and s.objects).most_common(3)]
        out = []
        for v, o in acts:
            subj = {"verb": v, "objects": [o]}
            for q in ({"operation": "where", "subject": subj}, {"operation": "count", "subject": subj},
                      {"operation": "next", "subject": subj}, {"operation": "list", "relation": "after",
                                                               "anchor": subj}):
                out.append(recall(view, P, q, lex).model_dump(mode="json"))
        vocab = Vocabulary.of(view, lex)
        out.append([list(vocab.words.items()), list(vocab.segments.items()),
                    [(c, list(n.items())) for c, n in vocab.names.items()]])
        return out


def _record(bank) -> dict:
    return Bank(bank).derived.get(P, f"derived-{wordings.NAME}")


def _write(bank, data, key: str | None = None) -> None:
    """A file as `derived.save` writes one, recorded in the manifest (under `key`, default the
    recorded one): a consistent file and record."""
    body = json.dumps(data).encode()
    _file(bank).write_bytes(body)
    Bank(bank).derived.put(P, f"derived-{wordings.NAME}", {"of": key or _record(bank)["of"],
                                                           "files": {_file(bank).name: sha256_bytes(body)}})


def _no_parsing(monkeypatch) -> None:
    def refuse(*_a, **_k):
        raise AssertionError("a wording was parsed again")

    monkeypatch.setattr(query_log, "_step_classes", refuse)
    monkeypatch.setattr(query_vocabulary, "_phrases", refuse)


def _counting(monkeypatch) -> list:
    calls = []
    real = query_log._step_classes

    def counted(*a, **k):
        calls.append(a[0])
        return real(*a, **k)

    monkeypatch.setattr(query_log, "_step_classes", counted)
    return calls


def test_a_new_process_reads_the_saved_wordings_and_answers_the_same(bank, lex, monkeypatch):
    first = _answers(bank, lex)  # reads every wording, and saves them
    saved = _file(bank)
    assert saved.is_file()
    with monkeypatch.context() as m:
        _no_parsing(m)
        assert _answers(bank, lex) == first  # nothing parsed: every wording came from the file


@pytest.mark.parametrize("spoil", ["payload", "truncated", "unrecorded", "key", "shape"])
def test_a_stale_or_damaged_file_is_not_trusted_and_is_written_again(bank, lex, monkeypatch, spoil):
    first = _answers(bank, lex)
    saved = _file(bank)
    assert _record(bank)["files"] == {saved.name: sha256_bytes(saved.read_bytes())}  # recorded as saved
    data = json.loads(saved.read_bytes())
    if spoil == "payload":  # a changed class, its record left as it was
        data["log"][0][4] = ["wrong:class"]
        saved.write_bytes(json.dumps(data).encode())
        row = next(r for r in verify_bank(bank, [P]).rows if r["participant"] == P)
        assert any(saved.name in p and "not as recorded" in p for p in row["problems"])  # `memora verify` names it
    elif spoil == "truncated":
        saved.write_bytes(saved.read_bytes()[:-100])
    elif spoil == "unrecorded":  # a file the manifest has no record of
        Bank(bank).derived.drop(P, f"derived-{wordings.NAME}")
    elif spoil == "key":  # saved under another lexicon or code: wrong classes, hash and all consistent
        data["log"] = [[*r[:4], ["wrong:class"], ["wrong:class"], None] for r in data["log"]]
        _write(bank, data, key="0" * 64)
    else:  # a consistent file whose tables are not what the reader saves
        _write(bank, {"log": [[1, 2]], "text": 3})
    calls = _counting(monkeypatch)
    assert _answers(bank, lex) == first
    assert calls, "the wordings were read again"
    monkeypatch.undo()
    with monkeypatch.context() as m:  # ... and saved again, whole
        _no_parsing(m)
        assert _answers(bank, lex) == first


def test_new_wordings_are_added_to_the_file_old_ones_reused(bank, lex, monkeypatch):
    first = _answers(bank, lex)
    data = json.loads(_file(bank).read_bytes())
    kept = len(data["log"]) // 2  # as if saved before the other half of the wordings were remembered
    dropped = {tuple(r[:3]) for r in data["log"][kept:]}
    data["log"] = data["log"][:kept]
    _write(bank, data)
    calls = _counting(monkeypatch)
    assert _answers(bank, lex) == first
    assert len(calls) == len(dropped) and set(calls) == {d[0] for d in dropped}  # only the new ones read
    monkeypatch.undo()
    with monkeypatch.context() as m:
        _no_parsing(m)
        assert _answers(bank, lex) == first


def test_vocabulary_counts_as_a_walk_of_every_step(small_bank, lex):
    """The vocabulary, counted per wording, holds what a walk of the steps one by one counted:
    the same counts, the same segments per word, the same order of words and names."""
    with MemoryView.open(small_bank[0], P) as view:
        log = action_log(view, lex)
        rows = log.rows
        got = Vocabulary(Counter(), {}, {})
        got._add(log, np.arange(len(rows)), lex, {})
        want = Vocabulary(Counter(), {}, {})
        for w, sg in zip(rows.word.tolist(), rows.segment.tolist()):  # the walk it replaced
            text = rows.words[w][3].lower()
            for w_, c in query_vocabulary._phrases(lex, wordings.WORD.findall(text)):
                if c is None or " " in w_:
                    want.words[w_] += 1
                segs = want.segments.setdefault(w_, [])
                if len(segs) < 20 and (not segs or segs[-1] != rows.segments[sg]):
                    segs.append(rows.segments[sg])
                if c is not None and c in log.classes[w][2]:
                    want.names.setdefault(c, Counter())[w_] += 1
        assert list(got.words.items()) == list(want.words.items())
        assert list(got.segments.items()) == list(want.segments.items())
        assert [(c, list(n.items())) for c, n in got.names.items()] == \
            [(c, list(n.items())) for c, n in want.names.items()]
        assert any(len(s) == 20 for s in got.segments.values())


def test_the_key_changes_with_the_lexicon_and_the_code(lex, monkeypatch):
    """A file saved under one lexicon, or one version of the reading code, is stale under another."""
    now = wordings.key(lex)
    assert wordings.key(lex) == now == wordings.key(Lexicon.load())
    other = Lexicon({"take": ["take", "grab"]}, {"pan": ["pan"], "cup": ["cup", "mug"]}, {"pan": "cookware", "cup": "crockery"})
    assert wordings.key(other) != now
    monkeypatch.setattr(wordings, "_keys", {})
    monkeypatch.setattr(wordings, "READERS", wordings.READERS[:-1])  # as if one module's code were other
    assert wordings.key(lex) != now

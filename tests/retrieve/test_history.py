"""The persisted history index (retrieve/history.py) answers get_object_history as reading the
object's whole history from Kùzu does, for every object and history length, and after remembered
moments add to histories (the entities they touched are read from Kùzu again)."""

from __future__ import annotations

import json
import shutil

import pytest

from memora_graph.form.live import LiveWriter
from memora_graph.retrieve import MemoryView, call_tool
from memora_graph.retrieve.history import HistoryIndex, outline_parts
from memora_graph.retrieve.view import persist_bank

from support.live import moments

P = "P37"
LENGTHS = (1, 5, 60, 1000)


@pytest.fixture()
def bank(small_bank, tmp_path):
    path = tmp_path / "bank"
    shutil.copytree(small_bank[0], path, ignore=shutil.ignore_patterns("tools-*"))
    return path


def _answers(view: MemoryView, entities: list[str]) -> list[str]:
    out = []
    for e in entities:
        for n in LENGTHS:
            r = call_tool(view, "get_object_history", {"object_query": e, "max_entries": n}).as_json()
            out.append(json.dumps(r, sort_keys=True))
    return out


def test_the_index_gives_the_parts_the_outline_gives(bank, embedder):
    with MemoryView.open(bank, P, embedder, persist=False) as view:
        index = HistoryIndex.from_arrays(*HistoryIndex.build(view.frame("_tool_history_all")).arrays())
        long = max(view.entities, key=lambda e: view.entities[e]["n_observations"] or 0)
        assert index.parts(long, 1000).total > 60, "a history longer than the default shown"
        for e in sorted(view.entities):
            for n in LENGTHS:
                want = outline_parts(view.frame("_tool_history_outline", entity=e), n)
                want.tail = view.by_id("_tool_history_entry", want.tail_ids)
                got = index.parts(e, n)
                assert got == want, (e, n)
        assert index.parts("no-such-entity", 60).total == 0


def test_every_history_answer_is_the_same_from_the_persisted_index(bank, embedder):
    with MemoryView.open(bank, P, embedder, persist=False) as view:
        entities = sorted(view.entities)
        reference = _answers(view, entities)
    persist_bank(bank, [P])
    with MemoryView.open(bank, P, embedder) as view:
        assert view.history is not None
        assert _answers(view, entities) == reference
        assert view._store is None, "history answers read the persisted stores only: Kùzu stays closed"


def _parts(view: MemoryView, entity: str, n: int):
    got = view.history_parts(entity, n)
    if got.tail is None:
        got.tail = view.by_id("_tool_history_entry", got.tail_ids)
    return got


def test_remembered_moments_join_the_histories(bank, embedder):
    """A view reading the persisted index that takes in remembered moments (`absorb`, as a
    server's readers do) answers for the objects they touched with the index's parts and the
    new entries appended, the others from the index: the same parts as a view opened afterwards
    on the database."""
    persist_bank(bank, [P])
    view = MemoryView.open(bank, P, embedder)
    try:
        view.warm()
        assert view.history is not None
        deltas = []
        with LiveWriter(bank, P, embedder=embedder) as memory:
            for m in moments(12, video="P37_live"):
                deltas.append(memory.remember(m).delta)
        for d in deltas:
            view.absorb(d)
        grown = sorted({e for d in deltas for e in d["history"]})
        old = [e for e in grown if e in view.history._row]
        assert old, "the moments added to objects the index holds"
        # entries after an object's last (a video sorting after its others) are appended to the index's parts
        assert set(old) <= set(view._history_appended) and not set(old) & view._history_added
        untouched = sorted(set(view.history.entities) - set(grown))[:5]
        got = {(e, n): _parts(view, e, n) for e in grown + untouched for n in LENGTHS}
        segments = sorted({d["segment"] for d in deltas})
        got_segments = view.by_id("_tool_segment", segments)  # remembered: not in the kept rows
        got_events = view.fetch("_tool_video_events", video="P37_live")
    finally:
        view.close()
    with MemoryView.open(bank, P, embedder, persist=False) as fresh:
        want = {(e, n): _parts(fresh, e, n) for e in grown + untouched for n in LENGTHS}
        assert got_segments == fresh.by_id("_tool_segment", segments) and len(got_segments) == len(segments)
        assert got_events == fresh.fetch("_tool_video_events", video="P37_live") and got_events
    assert got == want
    assert all(any(v["video"] == "P37_live" for v in want[(e, 60)].videos) for e in old)


def test_kept_segment_rows_are_the_rows_kuzu_returns(bank, embedder):
    """Every segment read by key, and every video's state entries, from the rows kept with the
    stores (retrieve/rows.py) are the rows Kùzu returns, in its order; a key not held gives none,
    as Kùzu does; Kùzu stays closed."""
    with MemoryView.open(bank, P, embedder, persist=False) as view:
        ids = sorted(r["id"] for r in view.fetch("_tool_segment_rows"))
        want = view.by_id("_tool_segment", ids + ["P37_999#t0000"])
        videos = sorted(view.videos)
        want_events = [view.fetch("_tool_video_events", video=v) for v in videos + ["P37_999"]]
    persist_bank(bank, [P])
    with MemoryView.open(bank, P, embedder) as view:
        assert view._keyed("_tool_segment") is not None
        got = view.by_id("_tool_segment", ids + ["P37_999#t0000"])
        got_events = [view.fetch("_tool_video_events", video=v) for v in videos + ["P37_999"]]
        assert view._store is None
    assert [json.dumps(e) for e in got_events] == [json.dumps(e) for e in want_events] and all(want_events[:-1])
    assert len(got) == len(ids) and got == want
    assert [json.dumps(r) for r in got] == [json.dumps(r) for r in want]  # same fields, same order, same values


def test_closing_one_warm_view_leaves_another_frozen(bank, embedder):
    """`warm` puts what a view loaded out of the cyclic collector's reach (gc.freeze, process-wide);
    closing one of two warm views must not unfreeze what the other still holds, and closing the
    last gives everything back."""
    import gc

    persist_bank(bank, [P])
    before = gc.get_freeze_count()
    assert before == 0, "nothing else in the test process froze objects"
    first, second = MemoryView.open(bank, P, embedder), MemoryView.open(bank, P, embedder)
    try:
        first.warm()
        second.warm()
        frozen = gc.get_freeze_count()
        assert frozen > 0
        first.close()
        assert gc.get_freeze_count() >= frozen, "the open view's objects stay frozen"
    finally:
        first.close()
        second.close()
    assert gc.get_freeze_count() == 0

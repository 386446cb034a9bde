"""The activity log's steps as columns (retrieve/steps.py) and the reader's log over them
(agent/query/steplog.py): the same steps, in the same order, as parsing every segment into objects and
sorting them, and the same answers to the reader's filters and runs as a scan of those objects."""

from __future__ import annotations

import bisect
import json
import random
from collections import Counter

import numpy as np
import pytest

from memora_graph.agent.query.log import _step_classes, step_log
from memora_graph.agent.query.steplog import LogStep
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.steps import StepRows

WORDS = [("put the knife in the drawer", "knife", "put"), ("put the knife in the drawer", "spoon", "put"),
         ("take the plate from the cupboard", "plate", "take"), ("open the fridge", "fridge", "open"),
         ("close the fridge", "fridge", "close"), ("wash the plate", "plate", "wash"), ("", "cup", "take")]


@pytest.fixture(scope="module")
def lex():
    return Lexicon.load()


def _segments(rng: random.Random, videos: list[str], n: int, turn0: int = 0) -> list[dict]:
    out = []
    for i in range(n):
        steps = [{"narration": w[0], "object": w[1], "action": w[2], "timestamp": rng.choice([0.0, 1.5, 3.0, 7.0])}
                 for w in (rng.choice(WORDS) for _ in range(rng.randint(0, 3)))]
        v = rng.choice(videos)
        out.append({"id": f"{v}#t{turn0 + i:04d}", "video": v, "turn": turn0 + i, "t_start": 10.0 * (turn0 + i),
                    "action_breakdown": json.dumps(steps)})
    return out


def _objects(segs: list[dict], lex) -> list[LogStep]:
    """Every step as an object, parsed afresh: what the reader built before the columns."""
    out = []
    for seg in segs:
        for s in json.loads(seg["action_breakdown"]):
            c = _step_classes(s["narration"], s["object"], s["action"], lex)
            out.append(LogStep(seg["video"], seg["t_start"] + s["timestamp"], seg["id"], *c,
                               s["narration"] or f"{s['action']} {s['object']}".strip()))
    return out


def test_columns_hold_every_step_in_order_and_take_remembered_ones_in_their_place(lex, tmp_path):
    rng = random.Random(7)
    old = _segments(rng, ["P01_01", "P01_03"], 40)
    old.sort(key=lambda s: (s["video"], s["turn"]))
    expected = sorted(_objects(old, lex), key=lambda s: (s.video, s.t))
    rows = StepRows.build(old)
    assert list(step_log(rows, lex)) == expected
    header, arrays = rows.arrays()  # persisted and read back (json + .npy, as the stores hold them)
    header = json.loads(json.dumps(header))
    for k, a in arrays.items():
        np.save(tmp_path / f"{k}.npy", a)
    back = StepRows.from_arrays(header, {k: np.load(tmp_path / f"{k}.npy", mmap_mode="r") for k in arrays})
    assert list(step_log(back, lex)) == expected
    # remembered segments: an old video continued (times among its steps), a new video sorting first and
    # one sorting between the others, a segment without steps
    new = _segments(rng, ["P01_01", "P01_02", "A_new", "P01_03"], 25, turn0=3)
    new.append({"id": "P01_01#t0999", "video": "P01_01", "turn": 999, "t_start": 5.0, "action_breakdown": "[]"})
    log = step_log(back, lex)
    for chunk in (new[:1], new[1:10], new[10:]):
        for step in _objects(chunk, lex):
            bisect.insort_right(expected, step, key=lambda s: (s.video, s.t))
        grown = log.rows.added(chunk)
        log = step_log(grown, lex, {}, log)
        assert list(log) == expected


def test_the_reader_filters_and_runs_give_what_a_scan_of_the_steps_gives(lex):
    rng = random.Random(3)
    segs = sorted(_segments(rng, ["P02_01", "P02_02", "P02_03"], 60), key=lambda s: (s["video"], s["turn"]))
    log = step_log(StepRows.build(segs), lex)
    steps = list(log)
    assert len(steps) == len(log) and steps[5] == log[5] and steps[-1] == log[-1]
    preds = [lambda s: "plate" in s.objects, lambda s: s.verb == "put", lambda s: bool(s.place),
             lambda s: "fridge" in s.nouns and s.verb in ("open", "close"), lambda s: False]
    for pred in preds:
        got = log.where(pred)
        want = [s for s in steps if pred(s)]
        assert list(got) == want and len(got) == len(want)
        assert got.videos() == list(dict.fromkeys(s.video for s in want))
        assert got.segment_ids(4) == list(dict.fromkeys(s.segment for s in want))[:4]
        assert log.action_counts(got) == Counter((s.verb, s.objects[0] if s.objects else "") for s in want)
        assert list(log.action_counts(got)) == list(Counter((s.verb, s.objects[0] if s.objects else "") for s in want))
    runs: list[list[LogStep]] = []  # consecutive steps of one video with the same action
    for s in steps:
        if runs and (runs[-1][0].video, runs[-1][0].verb, runs[-1][0].objects[:1]) == (s.video, s.verb, s.objects[:1]):
            runs[-1].append(s)
        else:
            runs.append([s])
    assert [log[int(p)] for p in log.run_starts] == [r[0] for r in runs]
    for pred in preds:
        follow = [b[0] for a, b in zip(runs, runs[1:]) if a[0].video == b[0].video and pred(a[0])]
        assert [log[int(p)] for p in log.runs_followed(pred)] == follow
        windows = [tuple((r[0].verb, r[0].objects[0] if r[0].objects else "") for r in runs[max(0, i - 1):i + 3]
                         if r[0].video == run[0].video) for i, run in enumerate(runs) if pred(run[0])]
        assert log.run_windows(pred, 1, 2) == windows
    assert list(log.of_video("P02_02")) == [s for s in steps if s.video == "P02_02"]
    ids = [steps[3].segment, steps[-1].segment, "nope"]
    assert list(log.of_segments(ids)) == [s for s in steps if s.segment in ids]
    assert log.nouns == {n for s in steps for n in s.nouns} and log.verbs == {s.verb for s in steps if s.verb}


def test_a_writable_servers_log_takes_remembered_moments_in_and_holds_few_pending(tmp_path, monkeypatch, lex):
    """Remembered moments reach the readers' log from the writer's rows (no read of the log), in
    the order a fresh read of the database gives; a long stream with no `ask` is folded in every
    STEPS_PENDING_MAX moments rather than held."""
    from memora_graph.retrieve import view as view_mod
    from memora_graph.serve import MemoryService

    from memora_graph.serve import service as service_mod

    monkeypatch.setattr(view_mod, "STEPS_PENDING_MAX", 3)
    monkeypatch.setattr(service_mod, "PENDING_MAX", 3)
    texts = ["put the kettle on the counter", "take the knife from the drawer", "open the fridge", "wash the plate"]
    with MemoryService(tmp_path / "bank", "P01", writable=True) as service:
        service.call("remember", {"text": "open the cupboard", "video": "v2", "start": 1.0})
        view = service._views["P01"]
        service.call("ask", {"question": "Where does P01 keep the kettle?"})  # the log read once
        for i in range(8):
            service.call("remember", {"text": texts[i % 4], "video": ["v2", "v1", "v3"][i % 3], "start": 2.0 + i})
            assert len(view.__dict__.get("_steps_pending", [])) < 3
            assert len(service._pending) < 3  # the readers' queue is folded in, not held
        service.call("search_objects", {"query": "kettle"})  # the next call takes the rest in
        got = step_log(view.steps, lex)
        whole = StepRows.build(view.store.fetch("_open_action_log", participant="P01"))
        assert list(got) == list(step_log(whole, lex)) and len(got) == 9


def test_a_grown_log_derives_from_the_log_before_what_a_log_of_its_rows_derives_afresh(lex):
    """After remembers, the next `ask` mends the runs and per-wording tables of the log before
    (issue 36: a pass over 1.15 million steps per ask at 1,000 h); they must be those of a fresh
    log of the same rows: new videos sorting first, last and between, steps at equal times,
    steps joining a run, new wordings."""
    rng = random.Random(11)
    old = sorted(_segments(rng, ["P03_02", "P03_05"], 50), key=lambda s: (s["video"], s["turn"]))
    log = step_log(StepRows.build(old), lex)
    mended = 0
    for round_, videos in enumerate((["P03_02"], ["A_first", "P03_05", "P03_03"], ["Z_last", "P03_02"], ["P03_05"])):
        _ = log.all.run_starts(), log.nouns, log.pairs(), log.run_keys()  # derived, as an ask derives them
        chunk = _segments(rng, videos, 12, turn0=round_ * 3)
        chunk.append({"id": f"{videos[0]}#new{round_}", "video": videos[0], "turn": 0, "t_start": 0.0,
                      "action_breakdown": json.dumps([{"narration": f"stir the soup {round_}", "object": "soup",
                                                       "action": "stir", "timestamp": 0.0}])})
        grown = step_log(log.rows.added(chunk), lex, {}, log)
        fresh = step_log(grown.rows, lex)
        mended += "_all" in grown.__dict__
        assert np.array_equal(grown.all.run_starts(), fresh.all.run_starts())
        assert grown.nouns == fresh.nouns and grown.verbs == fresh.verbs
        assert grown.pairs()[0] == fresh.pairs()[0] and np.array_equal(grown.pairs()[1], fresh.pairs()[1])
        assert np.array_equal(grown.run_keys(), fresh.run_keys())
        for pred in (lambda s: s.verb == "put", lambda s: "soup" in s.nouns):
            assert np.array_equal(grown.runs_followed(pred), fresh.runs_followed(pred))
            assert grown.run_windows(pred, 1, 2) == fresh.run_windows(pred, 1, 2)
        log = grown
    assert mended == 4, "the runs were computed afresh, not mended"

"""The editor's repairs of imperfect perception (form/repair.py): a held object named another way,
and a missed open implied by a close. Both through perception of narrated actions, as a build runs them."""

from __future__ import annotations

import pytest

from memora_graph.form.editor import DeterministicPolicy, EntityEditor, RawPolicy
from memora_graph.form.repair import REPAIRS_ENV
from memora_graph.perceive.narration import perceive_video


@pytest.fixture(autouse=True)
def repairs_on(monkeypatch):
    monkeypatch.setenv(REPAIRS_ENV, "on")


def _action(i, start, verb, noun, classes, narration=None, extra=()):
    vid = {k: c for c, k in classes.verbs.items()}
    nid = {k: c for c, k in classes.nouns.items()}
    nouns = [noun, *extra]
    return {"narration_id": f"P01_150_{i}", "participant_id": "P01", "video_id": "P01_150", "start_s": start,
            "stop_s": start + 1.0, "narration": narration or f"{verb} {noun}", "verb": verb, "verb_key": verb,
            "verb_class": vid[verb], "noun": noun, "noun_class": nid[noun], "all_nouns": nouns,
            "all_noun_classes": [nid[n] for n in nouns]}


def _edit(actions, classes, policy=None):
    ed = EntityEditor("P01", policy or DeterministicPolicy())
    results = [ed.edit(s) for s in perceive_video("P01", "P01_150", actions, 60.0, classes)]
    return ed, results


def test_an_object_put_down_under_another_name_while_its_category_is_in_hand_is_the_held_object(epic_meta):
    classes, _ = epic_meta
    acts = [_action(0, 7.0, "take", "plate", classes), _action(1, 12.0, "put", "bowl", classes, "put bowl down")]
    ed, results = _edit(acts, classes)
    assert [e.kind for e in ed.live()] == ["plate"]  # no bowl was ever in this scene
    (op, _), = [(op, o) for op, o in results[1].ops if o.narration_id == "P01_150_1"]
    assert op.entity_id == "P01:plate" and "[repair: 'bowl' is P01:plate named another way" in op.reason
    assert op.changes["state"] == "placed" and op.changes["held_by"] == ""
    # the raw editor and the editor with the rules off keep two objects
    raw, _ = _edit(acts, classes, RawPolicy())
    assert "bowl" in {e.kind for e in raw.live()}


def test_no_alias_when_the_held_name_is_said_in_the_same_segment(epic_meta):
    classes, _ = epic_meta
    acts = [_action(0, 7.0, "take", "plate", classes), _action(1, 12.0, "take", "plate", classes),
            _action(2, 14.0, "put", "bowl", classes)]
    ed, _ = _edit(acts, classes)
    assert sorted(e.kind for e in ed.live()) == ["bowl", "plate"]


@pytest.mark.parametrize("setting", ["off", None])
def test_the_rules_are_off_unless_memora_repairs_is_on(epic_meta, monkeypatch, setting):
    classes, _ = epic_meta
    if setting is None:
        monkeypatch.delenv(REPAIRS_ENV)
    else:
        monkeypatch.setenv(REPAIRS_ENV, setting)
    acts = [_action(0, 7.0, "take", "plate", classes), _action(1, 12.0, "put", "bowl", classes)]
    ed, _ = _edit(acts, classes)
    assert sorted(e.kind for e in ed.live()) == ["bowl", "plate"]


@pytest.mark.parametrize("verb, held_too", [("take", False), ("put", True)])
def test_no_alias_when_the_new_name_is_taken_or_itself_in_hand(epic_meta, verb, held_too):
    classes, _ = epic_meta
    acts = [_action(0, 7.0, "take", "plate", classes)]
    if held_too:
        acts.append(_action(1, 8.0, "take", "bowl", classes))
    acts.append(_action(2, 12.0, verb, "bowl", classes))
    ed, results = _edit(acts, classes)
    assert sorted(e.kind for e in ed.live()) == ["bowl", "plate"]
    assert not any("[repair:" in op.reason for r in results for op, _ in r.ops)


def test_a_second_name_stands_for_the_object_for_the_rest_of_the_video(epic_meta):
    classes, _ = epic_meta
    acts = [_action(0, 7.0, "take", "plate", classes), _action(1, 12.0, "put", "bowl", classes),
            _action(2, 25.0, "take", "bowl", classes), _action(3, 28.0, "wash", "bowl", classes)]
    ed, results = _edit(acts, classes)
    assert [e.kind for e in ed.live()] == ["plate"]
    washed = [e for r in results for e in r.events if e["narration"] == "wash bowl"]
    assert [(e["entity"], e["state"]) for e in washed] == [("P01:plate", "washed")]


def test_a_close_after_an_unexplained_handling_restores_the_missed_open(epic_meta):
    classes, _ = epic_meta
    acts = [_action(0, 1.0, "use", "fridge", classes), _action(1, 3.0, "take", "milk", classes, "take milk from fridge",
                                                              extra=("fridge",)),
            _action(2, 6.0, "close", "fridge", classes)]
    ed, results = _edit(acts, classes)
    events = [e for r in results for e in r.events if e["entity"] == "P01:fridge"]
    restored = [e for e in events if e["narration"].startswith("(restored")]
    assert [(e["state"], e["t"]) for e in restored] == [("open", 1.0)]
    assert events[-1]["state"] == "closed"
    # with the open narrated, nothing is restored
    acts[0] = _action(0, 1.0, "open", "fridge", classes)
    ed, results = _edit(acts, classes)
    assert not any(e["narration"].startswith("(restored") for r in results for e in r.events)

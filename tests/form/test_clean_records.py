"""Bounds and clean records (issue 31, item 3): every time is finite and within the stated range
(perceive/bounds.py), refused with the field named wherever it enters; a moment whose words are
all unknown is kept as text with no new entity; a place or container named as a destination keeps
its state; entity names are the person's words without doubled words."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.errors import DataError
from memora_graph.form.live import LiveWriter, Moment
from memora_graph.perceive.bounds import MAX_VIDEO_SECONDS
from memora_graph.perceive.narrations import load_narrations
from memora_graph.store import Store


def _rows(bank, participant: str, cypher: str) -> list[dict]:
    with Store(Bank(bank).db_path(participant), read_only=True) as store:
        return store.query(cypher, {"p": participant}).to_dicts()


@pytest.mark.parametrize("start", ["1e308", "nan", "inf", "-inf", str(MAX_VIDEO_SECONDS + 1), "-1"])
def test_remember_refuses_a_time_out_of_range_naming_the_field(tmp_path, start):
    bank = tmp_path / "bank"
    res = CliRunner().invoke(main, ["remember", str(bank), "--participant", "P01", "--video", "v",
                                    "--start", start, "open the fridge"])
    assert res.exit_code != 0 and "field 'start'" in res.output, res.output
    assert "Traceback" not in res.output
    assert not (bank / "P01.kuzu").exists() or _rows(bank, "P01", "MATCH (g:Segment) WHERE g.participant = $p RETURN count(g) AS n") == [{"n": 0}]


@pytest.mark.parametrize("field,line", [("start", '{"video": "v", "start": NaN, "end": 2, "text": "open fridge"}'),
                                        ("end", '{"video": "v", "start": 0, "end": Infinity, "text": "open fridge"}'),
                                        ("end", '{"video": "v", "start": 0, "end": 1e308, "text": "open fridge"}')])
def test_remember_json_refuses_nan_and_infinity_naming_the_field(tmp_path, field, line):
    res = CliRunner().invoke(main, ["remember", str(tmp_path / "bank"), "--participant", "P01", "--json", line])
    assert res.exit_code != 0 and f"field '{field}'" in res.output, res.output


def test_a_narrations_file_with_a_time_out_of_range_names_row_and_field(tmp_path):
    path = tmp_path / "n.csv"
    path.write_text("video_id,start,end,text\nv1,0,2,open the fridge\nv1,3,1e308,close the fridge\n")
    with pytest.raises(DataError, match=r"n.csv: row 3, field 'end': expected seconds .* from 0 to 86400"):
        load_narrations(path, participant="P01")
    path.write_text("video_id,start,end,text\nv1,nan,2,open the fridge\n")
    with pytest.raises(DataError, match=r"n.csv: row 2, field 'start': .*not NaN or infinity"):
        load_narrations(path, participant="P01")
    ok = tmp_path / "ok.csv"
    ok.write_text(f"video_id,start,end,text\nv1,0,{MAX_VIDEO_SECONDS:.0f},open the fridge\n")
    assert load_narrations(ok, participant="P01")[0].height == 1, "the end of the range is in it"


def test_a_moment_of_unknown_words_is_kept_as_text_with_no_new_entity_and_the_answer_says_so(tmp_path):
    bank = tmp_path / "bank"
    with LiveWriter(bank, "P01") as memory:
        memory.remember(Moment("v", 0.0, 1.0, "take the cup"))
        done = memory.remember(Moment("v", 5.0, 6.0, "flibber the zorp quux"))
        assert not [o for o in done.ops if o["op"] == "ADD"], done.ops
        assert done.unknown_words == ["flibber", "zorp", "quux"]
        assert "remembered as its text" in done.as_dict()["note"] and "flibber" in done.as_dict()["note"]
        known = memory.remember(Moment("v", 9.0, 10.0, "robot grasps the screwdriver"))  # a verb form: kept
        assert any(o["op"] == "ADD" and o["object"] == "screwdriver" for o in known.ops)
        assert "note" not in known.as_dict()
    names = {r["name"] for r in _rows(bank, "P01", "MATCH (e:Entity) WHERE e.participant = $p RETURN e.name AS name")}
    assert names == {"cup", "screwdriver"}
    seg = _rows(bank, "P01", "MATCH (g:Segment) WHERE g.participant = $p AND g.t_start = 5.0 RETURN g.summary AS s")
    assert seg == [{"s": "flibber the zorp quux"}], "the text is remembered as written"


@pytest.mark.parametrize("setup,text,place,state", [
    ("close the cupboard", "put the cup in the cupboard", "cupboard", "closed"),
    ("close the cupboard", "take the cup from the cupboard", "cupboard", "closed"),
    ("close the drawer", "take the knife out of the drawer", "drawer", "closed"),
    ("wash the sink", "put the plate into the sink", "sink", "washed"),
    ("wash the plate", "put the bowl on the plate", "plate", "washed")])
def test_a_place_or_container_named_as_destination_or_source_keeps_its_state(tmp_path, setup, text, place, state):
    bank = tmp_path / "bank"
    with LiveWriter(bank, "P01") as memory:
        memory.remember(Moment("v", 0.0, 1.0, f"open the {place}"))
        before = {o["object"]: o for o in memory.remember(Moment("v", 2.0, 3.0, setup)).ops}
        assert before[place]["changes"]["state"] == state
        done = memory.remember(Moment("v", 5.0, 6.0, text))
        ops = {o["object"]: o for o in done.ops}
        assert "state" not in ops[place]["changes"], ops[place]
        obj = next(o for o in ops if o != place)
        assert ops[obj]["changes"].get("state") in ("inserted", "held", "placed", "removed"), ops[obj]
    states = {r["name"]: r["state"] for r in _rows(
        bank, "P01", "MATCH (e:Entity) WHERE e.participant = $p RETURN e.name AS name, e.state AS state")}
    assert states[place] == state


def test_a_destination_seen_first_is_observed_not_given_the_verbs_state(tmp_path):
    with LiveWriter(tmp_path / "bank", "P01") as memory:
        ops = {o["object"]: o for o in memory.remember(Moment("v", 0.0, 1.0, "put the cup in the cupboard")).ops}
    assert ops["cupboard"]["changes"]["state"] == "observed" and ops["cup"]["changes"]["state"] == "inserted"


@pytest.mark.parametrize("surface,key,name", [("breast:chicken", "chicken", "chicken breast"),
                                              ("liquid:washing:up", "liquid:washing", "washing up liquid"),
                                              ("chicken", "chicken", "chicken"),
                                              ("spoon:wooden", "spoon", "wooden spoon"),
                                              ("stock:chicken", "stock", "chicken stock")])
def test_entity_names_are_the_persons_words_without_doubled_words(surface, key, name):
    from memora_graph.perceive.narration import object_name, split_noun

    props, extra = split_noun(surface)
    adjectives = [v for v in (props.color, props.size, props.material) if v]
    assert object_name(surface, key, adjectives, extra) == name


def test_no_entity_of_a_built_bank_doubles_a_word(small_bank):
    bank, _ = small_bank
    for p in ("P09", "P37"):
        names = [r["name"] for r in _rows(bank, p, "MATCH (e:Entity) WHERE e.participant = $p RETURN e.name AS name")]
        doubled = [n for n in names if len(set(n.split())) != len(n.split())]
        assert names and doubled == [], (p, doubled)


@pytest.mark.parametrize("field,value", [("t_end", float("nan")), ("t_end", 1e308), ("t_start", float("inf"))])
def test_a_segment_record_refuses_times_out_of_range(field, value):
    from pydantic import ValidationError

    from memora_graph.records import LayeredSegment

    record = {"participant_id": "P01", "video_id": "v", "turn_id": 0, "t_start": 0.0, "t_end": 10.0, field: value}
    with pytest.raises(ValidationError, match=field):
        LayeredSegment.model_validate(record)

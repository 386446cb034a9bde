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

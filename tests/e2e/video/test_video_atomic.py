"""A video that fails halfway through decoding (it passes the probe, then the decoder hits the
damage) leaves the bank exactly as it was: no bank when there was none, the same files when
there was one. Only the model's words are scripted."""

from __future__ import annotations

import json

import pytest
from support.scripted_server import ScriptedServer, Turn

from memora_graph.bank import Bank
from memora_graph.errors import DataError
from memora_graph.perceive.video import probe_video
from memora_graph.testing.synthetic import make_synthetic_video
from memora_graph.pipeline import build_from_video

PERCEPTION = json.dumps({
    "environment": {"layout_description": "kitchen", "location_id": "sink_area", "zones": {}, "spatial_relations": []},
    "activity_narrative": {"summary": "washing a cup", "detailed_narrative": "washing a cup.",
                           "action_breakdown": [{"timestamp": 1.0, "action": "wash", "object": "cup"}]},
    "object_registry": {"cup": {"name": "cup", "first_seen": 1.0, "is_fixture": False, "visual_properties": {},
                                "spatial_info": {"location": "sink_area", "movement_trajectory": None},
                                "state": {"current_state": "washed", "held_by": None}}},
})
EDIT = json.dumps({"object_operations": [{"event": "ADD", "observation": 0, "object_id": "cup", "data": {"name": "cup"},
                                          "reason": "first sighting"}]})


@pytest.fixture(scope="module")
def damaged_video(tmp_path_factory):
    """23 s whose bytes from 60% to 85% are zeros: the container and packet headers still
    describe 23 s (the probe passes), the decoder fails after the first clip."""
    folder = tmp_path_factory.mktemp("damaged")
    whole = make_synthetic_video(folder / "whole.mp4", 23.0, width=160, height=120, fps=10, audio=False)
    data = bytearray(whole.read_bytes())
    a, b = int(len(data) * 0.6), int(len(data) * 0.85)
    data[a:b] = bytes(b - a)
    bad = folder / "kitchen_damaged.mp4"
    bad.write_bytes(bytes(data))
    probe_video(bad)  # passes
    return bad


def _build(bank, video, turns, **kw):
    with ScriptedServer(turns) as server:
        return build_from_video(bank, video, "P09", backend="openai", base_url=server.base_url, perception_model="m",
                                consolidation="deterministic", backend_options={"timeout_s": 10}, **kw)


def _snapshot(path):
    return sorted((str(p.relative_to(path)), p.stat().st_size, p.stat().st_mtime_ns) for p in path.rglob("*"))


def test_a_failure_mid_decode_leaves_no_bank_behind(tmp_path, damaged_video):
    bank = tmp_path / "bank"
    with pytest.raises(DataError, match=r"kitchen_damaged\.mp4: .*decod"):
        _build(bank, damaged_video, [Turn(content=PERCEPTION)] * 3 + [Turn(content=EDIT)] * 3)
    assert not bank.exists()


def test_a_failure_mid_decode_leaves_an_existing_bank_as_it_was(tmp_path, damaged_video, short_video):
    bank = tmp_path / "bank"
    _build(bank, short_video, [Turn(content=PERCEPTION)] * 3 + [Turn(content=EDIT)] * 3)
    before = _snapshot(bank)
    manifest = (bank / "manifest.json").read_text()
    with pytest.raises(DataError, match=r"kitchen_damaged\.mp4"):
        _build(bank, damaged_video, [Turn(content=PERCEPTION)] * 3 + [Turn(content=EDIT)] * 3)
    assert _snapshot(bank) == before and (bank / "manifest.json").read_text() == manifest
    with Bank(bank).open("P09") as s:  # and it still opens, checked against its record
        assert s.run("videos", participant="P09")["video"].to_list() == ["kitchen"]

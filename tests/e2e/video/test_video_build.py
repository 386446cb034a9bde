"""Building memory from video against a real OpenAI-compatible HTTP server on 127.0.0.1.

Only the model's words are scripted: the video is decoded for real, frames and audio travel as
multimodal chat content over HTTP, replies are validated and repaired, the editor's operations
are mapped and applied, and the graph is queried with the named queries.
"""

from __future__ import annotations

import json
import shutil

import pytest
from click.testing import CliRunner
from support.scripted_server import ScriptedServer, Turn

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.errors import DataError
from memora_graph.pipeline import build_from_video

USAGE = {"prompt_tokens": 4000, "completion_tokens": 700}


def obj(name, location, state="observed", held=None, trajectory=None, fixture=False, first_seen=1.0, **visual):
    return {"name": name, "first_seen": first_seen, "is_fixture": fixture, "visual_properties": visual,
            "spatial_info": {"location": location, "movement_trajectory": trajectory},
            "state": {"current_state": state, "held_by": held}}


def perception(location, summary, objects, steps=(), zones=None, relations=()):
    return json.dumps({
        "environment": {"layout_description": f"kitchen, mostly the {location}", "location_id": location,
                        "zones": zones or {}, "spatial_relations": list(relations)},
        "activity_narrative": {"summary": summary, "detailed_narrative": summary + ".",
                               "action_breakdown": [{"timestamp": t, "action": a, "object": o} for t, a, o in steps]},
        "object_registry": objects,
    })


CLIP0 = perception(
    "counter_area", "cutting bread on the counter",
    {"plate": obj("white plate", "counter_area", "dirty", color="white", material="ceramic"),
     "knife": obj("bread knife", "counter_area", "in use", held="right hand", color="silver", material="metal"),
     "sink": obj("sink", "sink_area", fixture=True),
     "hob": obj("hob", "stove_area", fixture=True)},
    steps=[(1.0, "take", "knife"), (4.0, "cut", "bread")],
    zones={"worktop": {"anchor": "cutting_board", "position": "counter_area", "contents": ["plate", "knife"]}},
    relations=["knife ON_TOP_OF plate", "hob LEFT_OF sink"],
)
CLIP1 = perception(
    "sink_area", "washing the plate at the sink",
    {"plate": obj("white plate", "sink_area", "washed", held="both hands", trajectory="counter_area -> sink_area",
                  first_seen=0.5, color="white"),
     "knife": obj("bread knife", "counter_area", "placed", color="silver"),
     "sponge": obj("sponge", "sink_area", "wet", held="right hand", color="yellow"),
     "sink": obj("sink", "sink_area", "running", fixture=True)},
    steps=[(0.5, "carry", "plate"), (3.0, "wash", "plate"), (6.0, "scrub", "plate")],
)
CLIP2 = perception(
    "cabinet_area", "taking a mug from the cupboard",
    {"plate": obj("white plate", "sink_area", "drying", color="white"),
     "mug": obj("red mug", "cabinet_area", "held", held="right hand", color="red", material="ceramic")},
    steps=[(0.5, "open", "cupboard"), (1.5, "take", "mug")],
)


def ops(*operations):
    return json.dumps({"object_operations": list(operations)})


# Registry numbers are the prompt's: live entities sorted by id (P01:hob, P01:knife, P01:plate, ...).
EDIT0 = ops(*({"event": "ADD", "observation": i, "object_id": n, "data": {"name": n}, "reason": "first sighting"}
              for i, n in enumerate(["plate", "knife", "sink", "hob"])))
EDIT1 = ops(
    {"event": "UPDATE", "observation": 0, "object_id": 3, "changes": {"state": "washed", "location": "sink_area",
                                                                        "held_by": "both hands"}, "reason": "carried to the sink and washed"},
    {"event": "UPDATE", "observation": 1, "object_id": 2, "changes": {"state": "placed", "held_by": None}, "reason": "put down"},
    {"event": "ADD", "observation": 2, "object_id": "sponge", "data": {"name": "sponge"}, "reason": "new"},
    {"event": "DELETE", "observation": 3, "object_id": 9, "reason": "no such record"},  # -> DELETE_INVALID; sink omitted
)
EDIT2 = ops(
    {"event": "ADD", "observation": 0, "object_id": "plate", "data": {"name": "plate"}, "reason": "plate again"},
    {"event": "UPDATE", "observation": 1, "object_id": 42, "changes": {"state": "held"}, "reason": "mug"},
)


def _build(bank, video, script, participant="P01", **kw):
    with ScriptedServer(script) as server:
        kw.setdefault("consolidation", "deterministic")  # the LLM consolidation has its own test below
        result = build_from_video(bank, video, participant, backend="openai", base_url=server.base_url,
                                  perception_model="scripted-omni", backend_options={"timeout_s": 10},
                                  **kw)
    return result, server


@pytest.fixture(scope="module")
def built(tmp_path_factory, short_video):
    bank = tmp_path_factory.mktemp("vbank") / "bank"
    script = [Turn(content=c, usage=USAGE) for c in (CLIP0, CLIP1, CLIP2)]
    script += [Turn(content=c, usage={"prompt_tokens": 900, "completion_tokens": 150}) for c in (EDIT0, EDIT1, EDIT2)]
    result, server = _build(bank, short_video, script)
    return bank, result, server


def test_scripted_build_writes_entities_state_changes_and_places(built):
    bank, result, _ = built
    assert result.videos[0]["turns"] == 3 and result.segments == 3
    with Bank(bank).open("P01") as s:
        entities = {r["object_id"]: r for r in s.rows("entities", participant="P01")}
        assert set(entities) == {"plate", "knife", "sink", "hob", "sponge", "mug"}
        assert (entities["plate"]["state"], entities["plate"]["location"]) == ("drying", "sink_area")
        assert entities["knife"]["state"] == "placed" and entities["mug"]["location"] == "cabinet_area"

        hist = s.run("object_history", participant="P01", object="plate", video=result.videos[0]["video"])
        assert hist["state"].to_list() == ["dirty", "observed", "washed", "drying"]
        assert hist["location"].to_list() == ["counter_area", "counter_area", "sink_area", "sink_area"]
        assert hist["op"].to_list() == ["ADD", "NOOP", "UPDATE", "UPDATE"]
        assert hist["t"].to_list() == pytest.approx([1.0, 10.5, 15.25, 21.0])  # trajectory spread over the clip
        moves = s.run("location_changes", participant="P01", object="plate", video=result.videos[0]["video"])
        assert moves.select("moved_from", "moved_to").rows() == [("counter_area", "sink_area")]

        places = s.run("places_most_used", participant="P01")
        assert dict(zip(places["place"], places["turns"])) == {"counter_area": 1, "sink_area": 1, "cabinet_area": 1}
        assert s.run("store_counts", participant="P01")["places"][0] == 4  # + stove_area, where the hob is
        spatial = s.query("MATCH (a:Place)-[r:SPATIAL]->(b:Place) RETURN a.location_id AS a, r.relation AS rel, b.location_id AS b")
        assert spatial.rows() == [("stove_area", "LEFT_OF", "sink_area")]

        segs = s.run("segments", participant="P01", video="kitchen")
        assert segs["turn"].to_list() == [0, 1, 2]
        assert segs["summary"][1] == "washing the plate at the sink"
        carried = s.query("MATCH (g:Segment) WHERE g.turn = 1 RETURN g.working_summary AS w")["w"][0]
        assert "cutting bread on the counter" in carried

        reasons = s.query("MATCH (o:EditOp) RETURN o.turn AS turn, o.op AS op, o.reason AS reason, o.policy AS policy")
        assert set(reasons["policy"]) == {"llm"}
        text = " | ".join(reasons["reason"])
        assert "[repair: ADD on existing id plate]" in text
        assert "[repair: UPDATE on unknown id 42]" in text
        assert "state observed -> running [FALLBACK_UPDATE: omitted by the editor model]" in text  # the sink

        calls = s.run("model_calls_by_role", participant="P01")
        by_role = {r["role"]: r for r in calls.to_dicts()}
        assert by_role["perception"]["calls"] == 3 and by_role["editor"]["calls"] == 3
        assert by_role["perception"]["tokens_in"] == 12000 and by_role["editor"]["tokens_out"] == 450
        assert by_role["perception"]["failed"] == 0 and by_role["perception"]["model"] == "scripted-omni"
        per_segment = s.run("model_calls_by_segment", participant="P01")
        assert per_segment["segment"].to_list() == ["kitchen#t0000", "kitchen#t0001", "kitchen#t0002"]
        assert per_segment["calls"].to_list() == [2, 2, 2]


def test_the_model_sees_frames_audio_context_and_a_numbered_registry(built):
    _, _, server = built
    first = server.requests[0]
    assert first["model"] == "scripted-omni"
    assert first["response_format"]["json_schema"]["name"] == "PerceptionReply"
    parts = first["messages"][1]["content"]
    kinds = [p["type"] for p in parts]
    assert kinds == ["text"] + ["image_url"] * 20 + ["input_audio"]  # Omni models get the clip's audio
    assert parts[1]["image_url"]["url"].startswith("data:image/jpeg;base64,")
    assert parts[-1]["input_audio"]["format"] == "wav"
    assert "timestamps are relative" in first["messages"][0]["content"].lower()
    second = server.requests[1]["messages"][1]["content"][0]["text"]
    assert "cutting bread on the counter" in second  # c_{t-1}
    assert "plate (white plate, dirty at counter_area)" in second  # ids offered for reuse
    last_clip = server.requests[2]["messages"][1]["content"]
    assert sum(p["type"] == "image_url" for p in last_clip) == 6  # the 3 s tail at 2 fps
    editor = server.requests[4]
    assert editor["response_format"]["json_schema"]["name"] == "EditorReply"
    prompt = editor["messages"][1]["content"]
    assert "[3] plate: white plate (color=white, material=ceramic) state=dirty at counter_area" in prompt
    assert '"trajectory": "counter_area -> sink_area"' in prompt


def test_invalid_replies_retry_once_then_fail_that_segment_only(tmp_path, short_video):
    truncated = CLIP1[: len(CLIP1) // 2]
    bad_ops = ops({"event": "UPDATE", "observation": 0, "object_id": 3})  # UPDATE without changes
    script = [Turn(content=CLIP0, usage=USAGE), Turn(content="{not json"), Turn(content=truncated),
              Turn(content=CLIP2, usage=USAGE), Turn(content=EDIT0), Turn(content=bad_ops), Turn(content=bad_ops)]
    result, server = _build(tmp_path / "bank", short_video, script)
    assert server.pending == 0
    repair = server.requests[2]["messages"]
    assert repair[-2] == {"role": "assistant", "content": "{not json"}
    assert "could not be used" in repair[-1]["content"]
    video = result.videos[0]
    assert (video["turns"], video["segments"], video["perception_failed"], video["editor_failed"]) == (3, 1, [1], [2])
    with Bank(tmp_path / "bank").open("P01") as s:
        assert s.run("segments", participant="P01", video="kitchen")["turn"].to_list() == [0]
        for table in ("StateEvent", "EditOp"):
            turns = s.query(f"MATCH (x:{table}) RETURN DISTINCT x.turn AS turn")["turn"].to_list()
            assert turns == [0], table  # nothing of the failed segments was written
        assert s.query("MATCH (v:Video) RETURN v.n_turns AS n")["n"][0] == 3
        failed = s.run("model_calls_failed", participant="P01")
        assert failed.select("turn", "role", "repairs").rows() == [(1, "perception", 1), (2, "editor", 1)]
        assert "after one repair turn" in failed["error"][0]


def _snapshot(path):
    return sorted((str(p.relative_to(path)), p.stat().st_size, p.stat().st_mtime_ns) for p in path.rglob("*"))


@pytest.mark.parametrize("content", [b"", b"\x00\x01garbage" * 500])
def test_a_corrupt_or_empty_file_leaves_the_bank_untouched(built, tmp_path, content):
    bank, _, _ = built
    copy = tmp_path / "bank"
    shutil.copytree(bank, copy)
    before = _snapshot(copy)
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(content)
    with ScriptedServer([]) as server:
        with pytest.raises(DataError, match="broken.mp4"):
            build_from_video(copy, bad, "P01", backend="openai", base_url=server.base_url, perception_model="m")
    assert server.requests == []
    assert _snapshot(copy) == before


def test_offline_backend_says_plainly_what_video_needs(tmp_path, short_video):
    result = CliRunner().invoke(main, ["build", str(tmp_path / "bank"), "--video", str(short_video), "--participant", "P01"])
    assert result.exit_code == 1
    assert "needs a vision-language model" in result.output
    assert "--backend openai" in result.output and "--base-url" in result.output and "--perception-model" in result.output
    assert not (tmp_path / "bank").exists()


# LLM consolidation of the one video (segment handles S1..S3 are its three turns), across videos
# (finding F1), then enrichment: routine skills and generated preferences (none cited here)
CONSOLIDATE_VIDEO = json.dumps({"storage_preferences": [
    {"object": "plate", "preferred_location": "sink_area", "context": "after_use", "confidence": 0.7,
     "supporting_episodes": ["S1", "S2"]}], "organizational_habits": [], "workflow_patterns": [], "action_sequences": []})
CONSOLIDATE_ACROSS = json.dumps({"storage_preferences": [
    {"object": "plate", "preferred_location": "sink_area", "context": "after_use", "confidence": 0.8,
     "supporting_episodes": ["F1"]}], "organizational_habits": [], "workflow_patterns": [], "action_sequences": []})
ENRICH = (json.dumps({"routine_skills": []}), json.dumps({"generated_preferences": []}))


def test_cli_build_resume_and_stats(tmp_path, short_video):
    """The default video build consolidates by model too (the paper's consolidation / enrichment)."""
    bank = str(tmp_path / "bank")
    script = [Turn(content=c, usage=USAGE) for c in (CLIP0, CLIP1, CLIP2)] + [Turn(content=c) for c in (EDIT0, EDIT1, EDIT2)]
    script += [Turn(content=c) for c in (CONSOLIDATE_VIDEO, CONSOLIDATE_ACROSS, *ENRICH)]
    runner = CliRunner()
    with ScriptedServer(script) as server:
        args = ["build", bank, "--video", str(short_video), "--participant", "P02", "--video-id", "P02_kitchen",
                "--backend", "openai", "--base-url", server.base_url, "--perception-model", "qwen-vl", "--quiet"]
        first = runner.invoke(main, args)
        assert first.exit_code == 0, first.output
        again = runner.invoke(main, args)  # resumes: nothing to do, no model call
        assert again.exit_code == 0 and "already built" in again.output, again.output
    assert len(server.requests) == 10  # the resume made no call, not even consolidation
    assert all(p["type"] != "input_audio" for p in server.requests[0]["messages"][1]["content"])  # VL: no audio
    assert "6 entities" in first.output and "6 model calls (0 failed" in first.output
    roles = runner.invoke(main, ["stats", bank, "--calls", "--json"])
    assert {r["role"]: r["calls"] for r in json.loads(roles.output)} == {
        "editor": 3, "perception": 3, "consolidation": 2, "enrichment": 2}
    with Bank(bank).open("P02") as s:
        prefs = s.query("MATCH (p:Preference)-[:SUPPORTED_BY]->(g:Segment) WHERE p.participant = 'P02' "
                        "RETURN p.statement AS statement, p.processor AS processor, g.id AS segment ORDER BY segment")
    assert set(prefs["processor"]) == {"llm"} and all("plate" in t for t in prefs["statement"])
    assert prefs["segment"].to_list() == ["P02_kitchen#t0000", "P02_kitchen#t0001"]
    segments = json.loads(runner.invoke(main, ["stats", bank, "--calls", "segment", "--json"]).output)
    # perception and editor calls per segment; consolidation calls belong to no segment
    assert [r["segment"] for r in segments if r["segment"]] == ["P02_kitchen#t0000", "P02_kitchen#t0001",
                                                                "P02_kitchen#t0002"]
    usage = runner.invoke(main, ["build", bank, "--participant", "P02"])
    assert usage.exit_code == 2 and "only apply with --video" in usage.output

"""The model-backed processors without a server: reply -> layered record, operations -> EditOps."""

from __future__ import annotations

import numpy as np
import pytest

from memora_graph.form.editor import EntityState
from memora_graph.form.llm_editor import EditorReply, LLMEditorPolicy, ObjectOperation
from memora_graph.llm import get_backend
from memora_graph.llm.backends import ModelUnavailableError
from memora_graph.perceive.video import VideoClip
from memora_graph.perceive.vlm import OFFLINE_MESSAGE, PerceptionContext, PerceptionReply, VLMPerception, to_segment
from memora_graph.records import ObjectObservation


def _reply(**objects) -> PerceptionReply:
    return PerceptionReply.model_validate({
        "environment": {"location_id": "Left of the Sink", "spatial_relations": ["cup LEFT_OF kettle", "nonsense"]},
        "activity_narrative": {"summary": "making tea",
                               "action_breakdown": [{"timestamp": 6.0, "action": "Pour", "object": "kettle"},
                                                    {"timestamp": 2.0, "action": "take", "object": "cup_1"}]},
        "object_registry": objects,
    })


def test_reply_is_normalized_into_a_layered_segment():
    cups = {f"cup_{i}": {"name": "cup", "spatial_info": {"location": "worktop"}} for i in range(1, 7)}
    reply = _reply(**cups, **{"Red Kettle": {"name": "Red kettle", "first_seen": 9.5,
                                             "visual_properties": {"color": "Red", "shape": "round"},
                                             "spatial_info": {"location": "hob", "movement_trajectory": None},
                                             "state": {"current_state": "boiling", "held_by": None}}})
    clip = VideoClip("v", 2, 20.0, 28.0)  # an 8 s tail clip: timestamps are clamped to it
    seg = to_segment(reply, clip, "P01", "earlier: nothing")
    assert seg.environment.location_id == "sink_area"
    assert [r.text() for r in seg.environment.spatial_relations] == ["cup LEFT_OF kettle"]  # unknown relations dropped
    assert [(s.timestamp, s.action, s.end) for s in seg.activity.action_breakdown] == [(2.0, "take", 6.0), (6.0, "pour", 8.0)]
    ids = {o.object_id: o for o in seg.objects}
    assert set(ids) == {"cup", "red_kettle"}  # six numbered cups collapse into one
    kettle = ids["red_kettle"]
    assert (kettle.kind, kettle.location, kettle.state, kettle.t_rel) == ("kettle", "stove_area", "boiling", 8.0)
    assert kettle.attributes() == {"color": "red"}
    assert ids["cup"].location == "counter_area"


def test_reply_validation_rejects_out_of_clip_timestamps_and_missing_summary():
    with pytest.raises(ValueError):
        PerceptionReply.model_validate({"environment": {}, "activity_narrative": {
            "summary": "x", "action_breakdown": [{"timestamp": 12.0, "action": "take"}]}})
    with pytest.raises(ValueError):
        PerceptionReply.model_validate({"environment": {}, "activity_narrative": {"summary": ""}})


def test_working_summary_is_bounded():
    ctx = PerceptionContext(limit=120)
    for turn in range(10):
        seg = to_segment(_reply(mug={"name": "mug", "state": {"held_by": "right hand"}}), VideoClip("v", turn, 10.0 * turn, 10.0 * turn + 10), "P01")
        ctx.update(seg)
    text = ctx.summary()
    assert len(text) <= 120 and text.endswith("holding mug")
    assert ctx.known_ids() == ["mug"]


def test_offline_backend_cannot_perceive():
    with pytest.raises(ModelUnavailableError) as err:
        VLMPerception(get_backend("offline"), "P01")
    assert str(err.value) == OFFLINE_MESSAGE


def _entity(n: int, object_id: str, location="counter_area", **kw) -> EntityState:
    return EntityState(id=f"P01:{object_id}", participant="P01", object_id=object_id, kind=object_id, name=object_id,
                       location=location, state="clean", last_seen=float(n), **kw)


def _obs(object_id: str, location="counter_area", state="clean", **kw) -> ObjectObservation:
    return ObjectObservation(object_id=object_id, name=object_id.replace("_", " "), location=location, state=state, **kw)


@pytest.fixture()
def policy():
    return LLMEditorPolicy(get_backend("openai", base_url="http://127.0.0.1:9/v1", model="m"))


def test_operations_map_back_with_repairs(policy):
    registry = [_entity(1, "mug"), _entity(2, "plate"), _entity(3, "cup")]
    observations = [_obs("mug", "sink_area"), _obs("plate"), _obs("bowl"), _obs("cup")]
    groups = policy._groups(observations)
    reply = EditorReply.model_validate({"object_operations": [
        {"event": "noop", "observation": 0, "object_id": 1},  # NOOP but it moved -> UPDATE
        {"event": "DELETE", "observation": 1, "object_id": 3, "merged_into": 2, "reason": "cup is the plate"},
        {"event": "NOOP", "observation": 1, "object_id": "2"},
        {"event": "ADD", "object_id": "bowl", "data": {"name": "bowl"}},  # keyed by id, as in the paper
        # observation 3 (cup) omitted -> fallback on the registry's cup
    ]})
    out = policy.map_operations(reply.object_operations, observations, registry, groups)
    assert [[(o.op, o.entity_id) for o in ops] for ops in out] == [
        [("UPDATE", "P01:mug")],
        [("DELETE", "P01:cup"), ("NOOP", "P01:plate")],
        [("ADD", "")],
        [("NOOP", "P01:cup")],
    ]
    assert out[0][0].changes == {"location": "sink_area"} and "NOOP but the location changed" in out[0][0].reason
    assert out[1][0].merged_into == "P01:plate"
    assert "FALLBACK_NOOP" in out[3][0].reason
    assert policy.repairs == {"noop_moved": 1, "omitted": 1}


def test_add_on_an_existing_or_fuzzy_id_becomes_update(policy):
    registry = [_entity(1, "red_mug", color="red")]
    obs = [_obs("mug", "sink_area", visual_properties={"color": "red"}), _obs("mug_2")]
    ops = [ObjectOperation(event="ADD", observation=0, object_id="mug", data={"name": "mug"}),
           ObjectOperation(event="ADD", observation=1, object_id="mug_2", data={"name": "mug"})]
    out = policy.map_operations(ops, obs, registry, policy._groups(obs))
    assert (out[0][0].op, out[0][0].entity_id) == ("UPDATE", "P01:red_mug")  # 'mug' is contained in 'red_mug'
    assert out[1][0].op == "ADD"  # numbered look-alikes stay distinct


def test_invalid_operations_are_skipped_and_the_observation_still_lands(policy):
    registry = [_entity(1, "pan")]
    obs = [_obs("pan", state="dirty"), _obs("lid")]
    ops = [ObjectOperation(event="DELETE", observation=0, object_id=7),  # unknown: DELETE_INVALID
           ObjectOperation(event="UPDATE", observation=1, object_id=99, changes={"state": "on"}),  # unknown: ADD
           ObjectOperation(event="UPDATE", observation=5, object_id=1, changes={"state": "x"})]  # no such observation
    out = policy.map_operations(ops, obs, registry, policy._groups(obs))
    assert (out[0][0].op, out[0][0].changes) == ("UPDATE", {"state": "dirty"})  # FALLBACK_UPDATE
    assert out[1][0].op == "ADD" and "UPDATE on unknown id 99" in out[1][0].reason
    assert policy.repairs["delete_invalid"] == 1 and policy.repairs["no_observation"] == 1


def test_editor_reply_needs_data_for_add_and_changes_for_update():
    with pytest.raises(ValueError, match="ADD needs"):
        EditorReply.model_validate({"object_operations": [{"event": "ADD", "observation": 0, "object_id": "x"}]})
    with pytest.raises(ValueError, match="UPDATE needs"):
        EditorReply.model_validate({"object_operations": [{"event": "UPDATE", "observation": 0, "object_id": 1, "changes": {}}]})


def test_registry_is_prefiltered_to_the_prompt_budget(policy):
    rng = np.random.default_rng(0)
    entities = []
    for i in range(120):
        e = _entity(i, f"thing_{i:03d}x")
        e.emb = rng.normal(size=8).astype(np.float32)
        e.emb /= np.linalg.norm(e.emb)
        entities.append(e)
    target = entities[7]
    obs = [_obs("spatula")]

    def embed(text):
        return target.emb  # the observation looks most like entity 7

    chosen = policy.registry(obs, [entities], embed)
    assert len(chosen) == 50 and target in chosen
    exact = _entity(200, "spatula")
    chosen = policy.registry(obs, [entities + [exact]], embed)
    assert len(chosen) == 50 and exact in chosen and target in chosen

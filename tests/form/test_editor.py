import numpy as np

from memora_graph.form.editor import DeterministicPolicy, EntityEditor, RawPolicy
from memora_graph.records import LayeredSegment, ObjectObservation, VisualProperties


def seg(turn, *objects, video="P01_105"):
    return LayeredSegment(participant_id="P01", video_id=video, turn_id=turn, t_start=turn * 10.0,
                          t_end=turn * 10.0 + 10, objects=list(objects))


def obs(object_id, state, location, t_rel=0.0, **kw):
    return ObjectObservation(object_id=object_id, name=object_id.replace("_", " "), state=state,
                             location=location, t_rel=t_rel, **kw)


def test_paper_plate_is_one_entity_with_three_state_history():
    # The paper's example: a dirty plate at 40 s, 50 s and 540 s.
    ed = EntityEditor("P01")
    results = [ed.edit(seg(4, obs("plate", "idle", "counter_area"))),
               ed.edit(seg(5, obs("plate", "idle", "counter_area"))),
               ed.edit(seg(54, obs("plate", "being used", "counter_area")))]
    assert [e.id for e in ed.live()] == ["P01:plate"]
    events = [ev for r in results for ev in r.events]
    assert [(ev["t"], ev["state"], ev["op"]) for ev in events] == [
        (40.0, "idle", "ADD"), (50.0, "idle", "NOOP"), (540.0, "being used", "UPDATE")]
    assert ed.entities["P01:plate"].state == "being used"
    assert ed.entities["P01:plate"].n_observations == 3


def test_update_on_location_change_keeps_previous_state_in_history():
    ed = EntityEditor("P01")
    ed.edit(seg(1, obs("bowl", "placed", "counter_area")))
    r = ed.edit(seg(2, obs("bowl", "washed", "sink_area")))
    (op, _), = r.ops
    assert op.op == "UPDATE" and op.changes == {"state": "washed", "location": "sink_area"}
    assert r.events[0]["prev_location"] == "counter_area"


def test_attributes_split_and_join_identities():
    ed = EntityEditor("P01")
    ed.edit(seg(1, obs("spoon", "held", "counter_area", kind="spoon")))
    r = ed.edit(seg(2, obs("wooden_spoon", "held", "counter_area", kind="spoon",
                           visual_properties=VisualProperties(material="wooden"))))
    assert r.ops[0][0].op == "UPDATE" and r.ops[0][0].changes == {"material": "wooden"}
    r = ed.edit(seg(3, obs("metal_spoon", "held", "counter_area", kind="spoon",
                           visual_properties=VisualProperties(material="metal"))))
    assert r.ops[0][0].op == "ADD"
    assert sorted(e.material for e in ed.live()) == ["metal", "wooden"]


def test_duplicate_identifications_are_merged_by_delete():
    ed = EntityEditor("P01")
    ed.edit(seg(1, obs("cup", "placed", "counter_area")))
    # A second record of the same object (as a model editor might leave behind).
    dup = ed.entities["P01:cup"].__class__(**{**ed.entities["P01:cup"].__dict__, "id": "P01:cup#2", "n_observations": 1})
    ed.entities[dup.id] = dup
    r = ed.edit(seg(2, obs("cup", "held", "counter_area", held_by="hand")))
    kinds = [op.op for op, _ in r.ops]
    assert kinds == ["DELETE", "UPDATE"]
    deleted = [e for e in ed.entities.values() if e.status == "merged"]
    assert len(deleted) == 1 and deleted[0].merged_into in ed.entities
    assert len(ed.live()) == 1


def test_discarded_object_is_retracted_and_a_new_one_added_later():
    ed = EntityEditor("P01")
    ed.edit(seg(1, obs("onion_skin", "peeled", "counter_area")))
    r = ed.edit(seg(2, obs("onion_skin", "discarded", "bin_area", action="throw", narration="throw skin in bin")))
    assert r.ops[0][0].op == "DELETE"
    r = ed.edit(seg(3, obs("onion_skin", "peeled", "counter_area")))
    assert r.ops[0][0].op == "ADD" and r.ops[0][0].entity_id == "P01:onion_skin#2"


def test_same_object_twice_in_a_turn_is_one_record():
    ed = EntityEditor("P01")
    r = ed.edit(seg(1, obs("knife", "held", "counter_area", 1.0), obs("knife", "placed", "counter_area", 5.0)))
    assert [op.op for op, _ in r.ops] == ["ADD", "UPDATE"]
    assert len(ed.live()) == 1


def test_raw_policy_keeps_one_record_per_observation():
    ed = EntityEditor("P01", policy=RawPolicy())
    for t in range(3):
        ed.edit(seg(t, obs("plate", "idle", "counter_area")))
    assert len(ed.live()) == 3


class _SlicePolicy(DeterministicPolicy):
    same_kind_only = False  # reads the registry slice as a model's prompt does


def test_prompt_budget_prefilters_by_embedding_but_keeps_exact_names(embedder):
    ed = EntityEditor("P01", policy=_SlicePolicy(), embed=lambda s: embedder.encode([s])[0], prompt_budget=5)
    ed.edit(seg(0, *[obs(f"thing_{i}", "idle", "counter_area", kind=f"thing_{i}") for i in range(12)]))
    ed.edit(seg(1, obs("plate", "idle", "counter_area")))
    cands = ed.candidates(obs("plate", "held", "counter_area"))
    assert len(cands) <= 6 < len(ed.live()) and any(e.kind == "plate" for e in cands)
    # a policy that reads only its own kind gets exactly that, with no top-k over the registry
    ed.policy = DeterministicPolicy()
    assert [e.kind for e in ed.candidates(obs("plate", "held", "counter_area"))] == ["plate"]
    assert ed.candidates(obs("cup", "held", "counter_area")) == []
    r = ed.edit(seg(2, obs("plate", "held", "counter_area")))
    assert r.ops[0][0].op == "UPDATE"


def test_deterministic_policy_is_the_default():
    assert isinstance(EntityEditor("P01").policy, DeterministicPolicy)


def test_stale_merge_in_the_same_turn_is_dropped_not_readded():
    # Decisions for a turn are made against the registry at the start of the turn; a duplicate
    # retracted by the first observation must not be re-created by the second one's decision.
    ed = EntityEditor("P01")
    ed.edit(seg(1, obs("cup", "placed", "counter_area")))
    base = ed.entities["P01:cup"]
    for n in (2, 3):
        ed.entities[f"P01:cup#{n}"] = base.__class__(**{**base.__dict__, "id": f"P01:cup#{n}"})
    r = ed.edit(seg(2, *[obs("cup", s, "counter_area", float(i)) for i, s in enumerate(["held", "washed", "placed"])]))
    assert len(ed.live()) == 1
    assert [op.op for op, _ in r.ops].count("DELETE") == 2
    assert len(r.events) == 3  # every observation still lands in the history


def _reference_slice(entities, q, k, kind):
    """The candidate slice as first written: a stable sort of every live entity's similarity."""
    live = [e for e in entities.values() if e.status == "active"]
    if len(live) <= k:
        return live
    sims = np.stack([e.emb for e in live]) @ q
    top = set(np.argsort(-sims, kind="stable")[:k].tolist())
    return [e for i, e in enumerate(live) if i in top or e.kind == kind]


def test_live_index_slices_as_the_stable_sort_does_through_adds_and_deletes():
    """The registry's live index (kept up to date per edit, not rebuilt per segment) gives the
    slice a stable sort over every live entity gives: ties by registry order, deleted entities
    never, every entity of the observed kind."""
    from memora_graph.form.editor import EntityState, _LiveIndex

    rng = np.random.default_rng(0)
    # few distinct small-integer vectors: many exact ties, and dot products exact in float32
    # whatever the summation order (BLAS may sum a row differently with its position)
    basis = rng.integers(-3, 4, size=(6, 8)).astype(np.float32)
    entities = {}

    def new(i):
        e = EntityState(id=f"e{i}", participant="P01", object_id=f"o{i}", kind=f"k{i % 7}", name=f"o{i}")
        e.emb = basis[rng.integers(len(basis))].copy()
        return e

    for i in range(40):
        entities[f"e{i}"] = new(i)
    index = _LiveIndex(entities, lambda e: e.emb)
    for step in range(200):
        if rng.random() < 0.6:
            e = new(40 + step)
            entities[e.id] = e
            index.add(e)
        else:
            alive = [e for e in entities.values() if e.status == "active"]
            victim = alive[rng.integers(len(alive))]
            index.remove(victim.id)
            victim.status = "merged"
        q = basis[rng.integers(len(basis))] + (0 if step % 2 else rng.integers(-2, 3, size=8).astype(np.float32))
        k, kind = int(rng.integers(1, 30)), f"k{rng.integers(8)}"
        want = [e.id for e in _reference_slice(entities, q, k, kind)]
        got = index.live() if index.count <= k else index.nearest(q, k, kind)
        assert [e.id for e in got] == want, step
    assert index.count == sum(e.status == "active" for e in entities.values())

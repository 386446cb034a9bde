"""Offline consolidation and enrichment: rules on a hand-built memory, evidence, idempotence, --episodic."""

from __future__ import annotations

import json
import shutil

import pytest

from memora_graph.bank import Bank
from memora_graph.consolidate import (
    Processors, finish_participant, get_processors, infer, load_memory, register_processor,
)
from memora_graph.consolidate.memory import Obj, ParticipantMemory, MemoryStep
from memora_graph.consolidate.records import Consolidation, Enrichment, GeneratedPreference, RoutineSkill
from memora_graph.errors import MemoraError
from memora_graph.store import Store

SMALL = ("P09", "P37")


def _step(video, turn, t, verb, *objects, dest="", rel="", loc="sink_area", zone="", narration=""):
    objs = [Obj(kind, f"P01:{kind}", cat, fixture) for kind, cat, fixture in objects]
    return MemoryStep(video=video, segment=f"{video}#t{turn:04d}", t=t, verb=verb, objects=objs, location=loc, zone=zone,
                destination=dest, relation=rel, narration=narration or f"{verb} {objects[0][0]}")


BOWL = ("bowl", "crockery", False)
PLATE = ("plate", "crockery", False)
SPONGE = ("sponge", "cleaning equipment and material", False)
RACK = ("drying_rack", "storage", True)
EGG = ("egg", "dairy and eggs", False)
SPATULA = ("spatula", "utensils", False)
FORK = ("fork", "cutlery", False)
KNIFE = ("knife", "cutlery", False)


def _dishes(video: str, t0: float) -> list[MemoryStep]:
    """Take the sponge, wash the bowl and the plate, put both on the drying rack."""
    return [
        _step(video, int(t0 // 10), t0, "take", SPONGE),
        _step(video, int(t0 // 10), t0 + 2, "wash", BOWL, SPONGE, narration="wash bowl with sponge"),
        _step(video, int(t0 // 10), t0 + 5, "put", BOWL, RACK, dest="drying_rack", rel="ON_TOP_OF"),
        _step(video, int((t0 + 8) // 10), t0 + 8, "wash", PLATE, SPONGE, narration="wash plate with sponge"),
        _step(video, int((t0 + 11) // 10), t0 + 11, "put", PLATE, RACK, dest="drying_rack", rel="ON_TOP_OF"),
    ]


def _memories(small_bank) -> list[ParticipantMemory]:
    """The hand-made memory, then each SMALL participant's as `load_memory` reads it."""
    memories = [_memory()]
    for p in SMALL:
        with Bank(small_bank[0]).open(p, read_only=True) as store:
            memories.append(load_memory(store, p))
    return memories


def _memory() -> ParticipantMemory:
    steps = _dishes("P01_101", 10.0) + _dishes("P01_102", 50.0) + _dishes("P01_103", 100.0)
    eggs = [  # only in one video: a tool preference (repeated evidence), never a cross-video habit
        _step("P01_103", 30, 300.0, "mix", EGG, SPATULA, loc="stove_area", narration="stir egg using spatula"),
        _step("P01_103", 31, 310.0, "mix", EGG, SPATULA, loc="stove_area", narration="stir egg with spatula"),
        _step("P01_103", 32, 320.0, "mix", EGG, FORK, loc="stove_area", narration="mix egg with fork"),
        _step("P01_103", 40, 400.0, "cut", ("bread", "baked goods and grains", False), KNIFE, loc="counter_area"),
    ]
    steps += eggs
    segments = sorted({(s.segment, s.video) for s in steps})
    return ParticipantMemory("P01", [{"id": sid, "video": v} for sid, v in segments], steps)


def _ids(memory: ParticipantMemory) -> set[str]:
    return {o.entity for s in memory.steps for o in s.objects}


def test_rules_find_what_repeats_across_videos_and_cite_it():
    memory = _memory()
    k = infer(memory, _ids(memory), get_processors())
    c, e = k.consolidation, k.enrichment

    after_use = {(p.object, p.preferred_location) for p in c.storage_preferences if p.context == "after_use"}
    assert ("bowl", "drying rack") in after_use and ("plate", "drying rack") in after_use
    habits = {(h.trigger, h.next_action): h for h in c.organizational_habits}
    assert ("wash bowl", "put bowl on drying rack") in habits
    assert habits[("wash bowl", "put bowl on drying rack")].count == 3
    assert not any("egg" in h.trigger for h in c.organizational_habits), "one video is not a habit"
    flows = [w for w in c.workflow_patterns if w.category == "crockery"]
    assert flows and set(flows[0].objects) == {"bowl", "plate"} and "drying rack" in flows[0].pattern
    seqs = [a for a in c.action_sequences if a.steps[:3] == ["take sponge", "wash bowl", "put bowl on drying rack"]]
    assert seqs and len(seqs[0].videos) == 3
    assert all(len(a.videos) >= 2 for a in c.action_sequences)

    goals = {r.goal: r for r in e.routine_skills}
    assert "wash bowl" in goals
    wash = goals["wash bowl"]
    assert wash.count == 3 and sorted(wash.videos) == ["P01_101", "P01_102", "P01_103"]
    assert "wash bowl" in wash.canonical_steps and "drying rack" in wash.key_objects

    tools = {p.context: p for p in e.generated_preferences if p.subtype == "tool"}
    egg = tools["mix egg"]
    assert egg.preference.startswith("Usually uses the spatula to mix the egg") and "fork" in egg.preference
    assert egg.alternatives == {"fork": 1} and egg.count == 2
    assert {"spatula", "egg", "stir"} <= set(egg.keywords)
    assert set(egg.supporting_evidence_ids) == {"P01_103#t0030", "P01_103#t0031"}
    assert "cut bread" not in tools, "a single observation is not a preference"

    segs = memory.segment_ids
    for r in k.routines + k.preferences:
        assert r["supporting_episodes"] and set(r["supporting_episodes"]) <= segs
    assert k.dropped_ids == 0
    assert infer(memory, _ids(memory), get_processors()).routines == k.routines, "deterministic"


class _Inventing:
    """A stand-in for an LLM processor that cites an episode which does not exist."""

    name = "inventing"

    def consolidate_video(self, memory, video):
        return get_processors().consolidation.consolidate_video(memory, video)

    def consolidate_participant(self, memory, per_video):
        return Consolidation(participant=memory.participant)

    def enrich(self, memory, consolidation):
        real = sorted(memory.segment_ids)[0]
        return Enrichment(participant=memory.participant, routine_skills=[
            RoutineSkill(goal="invented", activity_type="routine_reproduction", canonical_steps=["dream"],
                         supporting_episodes=["P01_999#t0001"], segments=["P01_999#t0001"], count=1, confidence=0.9),
        ], generated_preferences=[
            GeneratedPreference(subtype="tool", preference="half real", count=2, confidence=0.5,
                                supporting_evidence_ids=[real, "P99_000#t0000"], entities=["P01:ghost"]),
        ])


def test_processor_registry_and_evidence_that_does_not_exist_is_dropped():
    with pytest.raises(MemoraError, match="deterministic"):
        get_processors("nope")
    with pytest.raises(MemoraError, match="already registered"):
        register_processor("deterministic", lambda: None)
    inventing = _Inventing()
    memory = _memory()
    k = infer(memory, _ids(memory), Processors("inventing", inventing, inventing))
    made = [r for r in k.routines if r["source"] != "task_routine"]  # task records: from the typed steps
    prefs = [p for p in k.preferences if p["source"] != "tasks"]
    assert [r["goal"] for r in made] == [], "a routine with no real evidence is not written"
    assert len(prefs) == 1 and prefs[0]["supporting_episodes"] == [sorted(memory.segment_ids)[0]]
    assert k.about == [] and k.dropped_ids == 4  # the invented episode (cited twice), the other participant's, the ghost


def test_every_routine_and_preference_has_existing_supporting_evidence(small_bank):
    path, _ = small_bank
    bank = Bank(path)
    total = 0
    for p in SMALL:
        with bank.open(p) as store:
            rows = store.rows("_explore_evidence", participant=p)
            counts = store.rows("_inferred_counts", participant=p)[0]
        assert len(rows) == counts["routines"] + counts["preferences"]
        for r in rows:
            assert r["cited"], r["id"]
            assert set(r["cited"]) <= set(r["linked"]), f"{r['id']} cites segments it is not linked to"
            assert set(r["linked_participants"]) == {p}
        total += len(rows)
        entry = bank.manifest()["participants"][p]
        assert entry["consolidated"] is True and entry["counts"]["routines"] == counts["routines"]
    assert total > 0
    assert bank.manifest()["condition"] == "memora_full"


def test_rerun_is_idempotent_and_episodic_clears(small_bank, tmp_path, embedder):
    src, _ = small_bank
    shutil.copytree(src, tmp_path / "bank", ignore=shutil.ignore_patterns(".staging"))
    bank = Bank(tmp_path / "bank")
    p = "P37"

    def snapshot():
        with Store(bank.db_path(p)) as s:
            return s.rows("_explore_evidence", participant=p), s.rows("routines", participant=p)

    before = snapshot()
    finish_participant(bank, p, embedder)
    after = snapshot()
    assert json.dumps(after, sort_keys=True, default=str) == json.dumps(before, sort_keys=True, default=str)
    assert len({r["id"] for r in after[0]}) == len(after[0])

    finish_participant(bank, p, embedder, episodic=True)
    assert snapshot() == ([], [])
    data = bank.manifest()
    assert data["participants"][p]["consolidated"] is False and data["condition"] == "mixed"
    assert data["participants"][p]["counts"]["routines"] == 0

    finish_participant(bank, p, embedder)
    assert snapshot()[1] == before[1]
    assert bank.manifest()["condition"] == "memora_full"


def test_memory_slice_steps_group_one_narration(small_bank):
    path, _ = small_bank
    with Bank(path).open("P37") as store:
        memory = load_memory(store, "P37")
    assert memory.steps and memory.videos
    keys = [(s.video, s.t, s.narration) for s in memory.steps]
    assert len(keys) == len(set(keys)), "one step per narrated action"
    assert {s.segment for s in memory.steps} <= memory.segment_ids


def _as_list_path(memory: ParticipantMemory):
    from memora_graph.consolidate.rules import RuleConsolidator

    c = RuleConsolidator()
    return c.consolidate_participant(memory, [c.consolidate_video(memory, v) for v in memory.videos])


def test_streaming_merge_gives_the_records_of_the_whole_list_merge(small_bank):
    """Consolidation merges video by video (its memory does not grow with the hours); the records,
    their evidence and their order are those of merging every video's consolidation at once."""
    from memora_graph.consolidate.rules import RuleConsolidator

    memories = _memories(small_bank)
    for memory in memories:
        whole = _as_list_path(memory)
        streamed = RuleConsolidator().consolidate_streaming(memory)
        assert streamed.model_dump() == whole.model_dump()
    assert any(_as_list_path(m).action_sequences for m in memories[1:])  # the comparison covers sequences


def test_the_fold_index_kept_video_by_video_gives_the_whole_list_merge(small_bank):
    """The incremental merge (`FoldIndex`): videos put in any order, replaced by a changed version
    of themselves and removed, give after each change the records, evidence and order of merging
    the current videos at once."""
    import random

    from memora_graph.consolidate.records import VideoConsolidation
    from memora_graph.consolidate.rules import FoldIndex, RuleConsolidator

    memories = _memories(small_bank)
    rules = RuleConsolidator()
    for memory in memories:
        parts = {v: rules.consolidate_video(memory, v) for v in memory.videos}
        index, current = FoldIndex(rules), {}
        order = list(parts)
        random.Random(7).shuffle(order)

        def check():
            want = rules.consolidate_participant(memory, [current[v] for v in sorted(current)])
            assert index.consolidation(memory.participant).model_dump() == want.model_dump()

        for v in order:
            index.put(parts[v], v)
            current[v] = parts[v]
            check()
        for v in order[: max(1, len(order) // 2)]:  # a video changed: half its records
            half = VideoConsolidation(video=v, storage_preferences=parts[v].storage_preferences[::2],
                                      organizational_habits=parts[v].organizational_habits[1::2],
                                      workflow_patterns=parts[v].workflow_patterns[::2],
                                      action_sequences=parts[v].action_sequences[1::2])
            index.put(half, v)
            current[v] = half
            check()
        gone = order[-1]
        index.put(None, gone)
        del current[gone]
        check()


def test_steps_held_as_columns_are_the_steps_read_as_objects(small_bank):
    """`load_memory` keeps the steps as columns (`StepTable`) and makes a video's steps when they
    are read; they are the steps `StepReader.read` makes, and consolidation + enrichment over
    them give the records of the same memory held as lists."""
    from memora_graph.consolidate.memory import StepReader, merged_map
    from memora_graph.consolidate.rules import RuleConsolidator, RuleEnricher

    found = []
    for p in SMALL:
        with Bank(small_bank[0]).open(p, read_only=True) as store:
            memory = load_memory(store, p)
            sizes = {v: 1 for v in memory.videos}
            listed = StepReader(merged_map(store, p)).read(store, p, sizes)
            entity_ids = {r["id"] for r in store.fetch("_consolidate_entity_ids", participant=p)}
        assert memory.steps == listed and len(listed) > 100
        assert [s for v in memory.steps_by_video() for s in memory.steps_by_video()[v]] == listed
        assert memory.tokens() == {s.token for s in listed}
        as_lists = ParticipantMemory(p, memory.segments, listed)
        assert as_lists.videos == memory.videos and as_lists.segment_ids == memory.segment_ids
        assert RuleConsolidator().recurring(memory) == RuleConsolidator().recurring(as_lists)
        assert (RuleEnricher().enrich(memory, Consolidation(participant=p)).model_dump()
                == RuleEnricher().enrich(as_lists, Consolidation(participant=p)).model_dump())
        a, b = infer(memory, entity_ids, get_processors()), infer(as_lists, entity_ids, get_processors())
        assert (a.routines, a.preferences, a.supported_by, a.uses, a.about) == (
            b.routines, b.preferences, b.supported_by, b.uses, b.about)
        found += [*a.routines, *a.preferences]
    assert {r.get("subtype", r.get("source")) for r in found} >= {"routine_skill", "action_sequence", "storage", "habit"}


def test_recurring_n_grams_are_those_seen_in_at_least_two_videos(small_bank):
    """The n-grams counted as rows of token numbers are those a set of videos per n-gram gives."""
    from memora_graph.consolidate.rules import RuleConsolidator

    rules = RuleConsolidator()
    memories = _memories(small_bank)
    seen = set()
    for memory in memories:
        videos: dict[tuple, set] = {}
        for video, steps in memory.steps_by_video().items():
            for tokens, _ in rules._windows(steps):
                videos.setdefault(tokens, set()).add(video)
        want = {t for t, vs in videos.items() if len(vs) >= rules.min_videos}
        assert RuleConsolidator().recurring(memory) == want
        seen |= want
    assert {len(t) for t in seen} == {3, 4, 5}

"""Planning Replay and Generalize generation: the paper's rules, checked against the calibration
files and worked synthetic cases, and registry enrichment."""

from __future__ import annotations

import pytest

from memora_graph.bench.behaviour import ActionClass, ActionRow, build_behaviours, noun_text
from memora_graph.bench.generate_generalize import FAMILIES, generate_generalize
from memora_graph.bench.generate_replay import (
    ReplayConfig, classify_task, enrich_narration, generate_replay, match_object, match_score, repeat_rate,
    segment_score, segment_video, select_tasks, task_query,
)
from memora_graph.bench.tasks import MatchedObject, load_suite
from memora_graph.perceive.annotations import load_annotations


@pytest.fixture(scope="module")
def calibration_behaviours():
    return build_behaviours(load_annotations(participants=["P01", "P02", "P03", "P04"]))


def test_segmentation_reproduces_every_calibration_replay_segment(calibration_behaviours):
    tasks = load_suite().replay_tasks()
    assert len(tasks) == 44
    for task in tasks:
        segments = segment_video(calibration_behaviours[task.participant_id].steps_by_video[task.video_id])
        index = int(task.task_id.rsplit("_", 1)[1])
        assert [s.narration_id for s in segments[index]] == [s.narration_id for s in task.ground_truth_steps], task.task_id


def test_typing_reproduces_every_calibration_task_type():
    for task in load_suite().replay_tasks():
        verbs = [s.verb for s in task.ground_truth_steps]
        nouns = [noun_text(s.noun) for s in task.ground_truth_steps]
        assert classify_task(verbs, nouns) == task.task_type, task.task_id


def test_typing_thresholds_worked_by_hand():
    # 3 cleanup of 8 non-filler verbs = .375 > .35
    assert classify_task(["wash", "rinse", "dry", "cut", "peel", "stir", "press", "press", "take"], []) == "cleanup_organization"
    # cleanup 2/6 = .33 (not > .35); prep 2/6 = .33 > .3
    assert classify_task(["wash", "rinse", "cut", "peel", "press", "press"], []) == "meal_preparation"
    # nothing reaches its threshold; largest .25 (cleanup and setup tie) -> setup wins ties
    assert classify_task(["wash", "turn-on", "press", "press"], []) == "object_retrieval_setup"
    # largest share 1/8 < .15 -> routine
    assert classify_task(["squeeze"] + ["press"] * 7, []) == "routine_reproduction"
    # only filler verbs: storage nouns decide
    assert classify_task(["take", "put"], ["fridge", "milk"]) == "object_retrieval_setup"
    assert classify_task(["take", "put"], ["milk", "cup"]) == "routine_reproduction"


def _step(i: int, start: float, verb: str = "take", stop: float | None = None) -> ActionRow:
    return ActionRow(f"P00_100_{i}", "P00_100", start, start + 1 if stop is None else stop, f"{verb} thing", verb, "thing",
                ActionClass(verb, "thing"), "", "", "annotation")


def test_segmentation_rules_worked_by_hand():
    # 4 steps, a 31 s gap (hard split), 4 steps
    steps = [_step(i, i * 2.0) for i in range(4)] + [_step(4 + i, 38 + i * 2.0) for i in range(4)]
    assert [len(s) for s in segment_video(steps)] == [4, 4]
    # a gap of exactly 30 s does not split
    steps = [_step(i, i * 2.0) for i in range(4)] + [_step(4 + i, 37 + i * 2.0) for i in range(4)]
    assert [len(s) for s in segment_video(steps)] == [8]
    # soft split: gap 12 s, cleanup -> prep, confirmed by the next step
    steps = [_step(0, 0, "wash"), _step(1, 2, "rinse"), _step(2, 4, "dry"), _step(3, 17, "cut"), _step(4, 19, "peel"), _step(5, 21, "cut")]
    assert [len(s) for s in segment_video(steps)] == [3, 3]
    # the same gap without confirmation (next step is general) does not split
    steps[4] = _step(4, 19, "take")
    assert [len(s) for s in segment_video(steps)] == [6]
    # a short head (2 steps) is merged forward; a short tail joins the previous segment
    steps = [_step(0, 0), _step(1, 2)] + [_step(2 + i, 40 + 2 * i) for i in range(4)] + [_step(6, 80)]
    assert [len(s) for s in segment_video(steps)] == [7]
    # 20 steps -> max(ceil(20/15), min(20//3, ceil(20/9))) = 3 near-even chunks: 7, 7, 6
    assert [len(s) for s in segment_video([_step(i, i * 2.0) for i in range(20)])] == [7, 7, 6]


def test_score_query_repeat_rate_and_selection():
    assert segment_score(["wash"] * 9) == pytest.approx(1 + 1 / 9 + 1)
    assert segment_score(["take", "wash", "cut"]) == pytest.approx((1 - 6 / 15) + 1 + 2 / 3)
    assert repeat_rate(["a", "a", "b", "b"]) == 0.5
    assert task_query("P05", "meal_preparation", ["peel", "cut"], ["onion", "knife"]) == "Help P05 peel and prepare the onion."
    assert task_query("P05", "cleanup_organization", ["take", "wipe"], ["cloth", "hob"]) == "Help P05 wipe down the hob."
    cands = [{"task_id": f"t{i:02d}", "video_id": "V", "task_type": "cleanup_organization" if i < 8 else "meal_preparation",
              "score": 3 - i / 100, "query": "Help P05 clean the sink.", "nouns": ["sink", f"n{i}"]} for i in range(10)]
    chosen = select_tasks(cands, ReplayConfig(per_participant=6, per_type=4))
    ids = [c["task_id"] for c in chosen]
    assert ids == ["t00", "t01", "t02", "t03", "t08", "t09"]  # 4 cleanup, then the other type
    assert len({c["query"] for c in chosen}) == 6  # duplicates disambiguated
    chosen = select_tasks(cands[:8], ReplayConfig(per_participant=6, per_type=4))
    assert len(chosen) == 6  # overflow fill when one type is all there is


def test_generated_replay_for_a_participant(behaviours):
    result = generate_replay(behaviours["P01"])
    assert 0 < len(result.tasks) <= 12
    ids = [t.task_id for t in result.tasks]
    assert len(set(ids)) == len(ids)
    for t in result.tasks:
        assert t.task_id.startswith(f"plan_{t.video_id}_") and t.task_query.startswith("Help P01 ")
        assert 3 <= t.num_steps <= 15 and t.repeat_rate <= 0.70
        assert all(s.matched_object is None for s in t.ground_truth_steps)  # no registry, no enrichment
        starts = [s.start_time for s in t.ground_truth_steps]
        assert starts == sorted(starts)
    for t in result.filtered:
        assert t.repeat_rate > 0.70


REGISTRY = [
    {"memory_id": "sink", "memory_name": "sink", "color": "silver", "material": "stainless steel", "location": "on counter"},
    {"memory_id": "dishcloth", "memory_name": "dishcloth", "color": "white", "material": "cotton", "location": "in hand"},
    {"memory_id": "faucet", "memory_name": "chrome faucet", "color": "silver", "material": "metal", "location": "sink_area"},
    {"memory_id": "milk_bottle", "memory_name": "white plastic milk bottle", "color": "clear", "material": "plastic", "location": ""},
    {"memory_id": "vacuum", "memory_name": "blue handheld vacuum cleaner", "color": "blue", "material": "plastic", "location": ""},
]


def test_match_scores_and_enriched_narration():
    objs = {o["memory_id"]: MatchedObject(**o) for o in REGISTRY}
    assert match_score("sink", objs["sink"]) == 10
    assert match_score("milk bottle", objs["milk_bottle"]) == 10  # equal to the id once '_' is a space
    assert match_score("bottle", objs["milk_bottle"]) == 8  # noun in id
    assert match_score("plastic milk", objs["milk_bottle"]) == 7  # noun in name only
    assert match_score("chrome faucet handle", objs["faucet"]) == 6  # reverse containment
    assert match_score("cloth", objs["dishcloth"]) == 6  # synonym equal to the name
    assert match_score("tap", objs["faucet"]) == 6  # synonym equal to the id
    assert match_score("bin", MatchedObject(memory_id="waste_01", memory_name="black trash can")) == 4  # synonym inside
    assert match_score("hand", objs["vacuum"]) == 0  # whole words: not 'handheld'
    assert match_score("steel sink", objs["sink"]) == 6
    registry = sorted(objs.values(), key=lambda o: o.memory_id)
    assert match_object("tap", registry).memory_id == "faucet"
    assert match_object("onion", registry) is None
    assert enrich_narration("wash sink", "sink", objs["sink"]) == "wash silver stainless steel sink on counter"
    assert enrich_narration("close tap", "tap", objs["faucet"]) == "close silver metal tap at sink_area"
    assert enrich_narration("rinse cloths", "cloth", objs["dishcloth"]) == "rinse white cotton cloths in hand"


def test_replay_enrichment_uses_only_the_registry(behaviours):
    plain = generate_replay(behaviours["P01"])
    enriched = generate_replay(behaviours["P01"], REGISTRY)
    assert [t.task_id for t in plain.tasks] == [t.task_id for t in enriched.tasks]
    n = 0
    for t in enriched.tasks:
        for s in t.ground_truth_steps:
            if s.matched_object is not None:
                n += 1
                assert s.matched_object.memory_id in {o["memory_id"] for o in REGISTRY}
                assert s.enriched_narration != s.narration
    assert n > 0
    # EPIC fields are unchanged by enrichment
    for a, b in zip(plain.tasks, enriched.tasks):
        assert [(s.narration, s.verb, s.noun, s.start_time) for s in a.ground_truth_steps] == \
               [(s.narration, s.verb, s.noun, s.start_time) for s in b.ground_truth_steps]
    # a registry entry tied to another video is not used
    other = [dict(o, video_id="P99_999") for o in REGISTRY]
    assert all(s.matched_object is None for t in generate_replay(behaviours["P01"], other).tasks for s in t.ground_truth_steps)


def test_generalize_families_and_gates(behaviours):
    b = behaviours["P01"]
    tasks = generate_generalize(b)
    by_type = {t: [x for x in tasks if x.task_type == t] for t in ("transfer", "composition", "fully_novel")}
    assert 1 <= len(by_type["transfer"]) <= 6 and len(by_type["fully_novel"]) == 3 and len(by_type["composition"]) <= 3
    assert len({t.task_id for t in tasks}) == len(tasks)
    for t in tasks:
        assert t.task_id.startswith(f"generalize_{'novel' if t.task_type == 'fully_novel' else t.task_type}_P01_")
        assert t.task_query.startswith("Help P01 ") and len(t.ground_truth_steps) >= 5
    per_action = {}
    for t in by_type["transfer"]:
        per_action[t.source_action] = per_action.get(t.source_action, 0) + 1
        verbs = FAMILIES[t.source_action][0]
        # never observed: no annotated step applies the family's verbs to the target
        done = [s for steps in b.steps_by_video.values() for s in steps
                if s.verb.split("-")[0] in verbs and noun_text(s.action.noun) == t.target_object]
        assert not done, t.task_id
        assert t.audit["family_count"] >= 5 and t.audit["source_count"] >= 1
        assert t.target_object in t.task_query
    assert max(per_action.values()) <= 2


def test_generalize_steps_are_grounded_in_the_registry(behaviours):
    registry = [{"memory_id": "knife", "memory_name": "knife", "color": "black", "material": "metal", "location": "on counter"},
                {"memory_id": "garlic", "memory_name": "garlic", "color": "white", "material": "", "location": "in the bowl"}]
    tasks = generate_generalize(behaviours["P01"], registry)
    cutting = [t for t in tasks if t.task_id.endswith("cutting_garlic")]
    assert cutting, [t.task_id for t in tasks]
    steps = " ".join(cutting[0].ground_truth_steps)
    assert "black metal knife" in steps and "white garlic" in steps and "from the bowl" in steps
    plain = [t for t in generate_generalize(behaviours["P01"]) if t.task_id.endswith("cutting_garlic")][0]
    assert "black metal knife" not in " ".join(plain.ground_truth_steps)

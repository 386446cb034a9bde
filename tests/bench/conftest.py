"""Fixtures for the MEMORA-Bench tests: a small real cohort from the bundled annotations, and (for the
evaluation runs) a raw bank and a tiny hand-written MEMORA-Bench release for P37 (the smallest participant)."""

from __future__ import annotations

import json

import pytest

COHORT = ["P01", "P09", "P23", "P37"]  # one rich participant, the two smallest, one with 2 videos


@pytest.fixture(scope="session")
def cohort_annotations():
    from memora_graph.perceive.annotations import load_annotations

    return load_annotations(participants=COHORT)


@pytest.fixture(scope="session")
def behaviours(cohort_annotations):
    from memora_graph.bench.behaviour import build_behaviours

    return build_behaviours(cohort_annotations)


@pytest.fixture(scope="session")
def generated(cohort_annotations):
    """The cohort's suite with seed 1, without the embedding check (exact dedup only)."""
    from memora_graph.bench.generate import generate_suite

    return generate_suite(cohort_annotations, seed=1, embedder=None)


# the evaluation runs' raw bank and tiny release (formerly tests/eval/conftest.py)
OPTION_E = "The information is not available based on the given context"
IMPORTANT = ("\n\nIMPORTANT: If the information needed to answer this question is not available in your memory or "
             "context, you MUST select option E. Only select A-D if you are confident the answer is supported by "
             "information you have access to.")


@pytest.fixture(scope="session")
def small_raw_bank(tmp_path_factory, embedder):
    from memora_graph.pipeline import build_bank

    path = tmp_path_factory.mktemp("rawbank") / "raw"
    build_bank(path, ["P37"], mode="raw")
    return path


@pytest.fixture(scope="session")
def tiny_tasks(tmp_path_factory, small_bank):
    """Two EAM-QA items (one answerable from P37's memory, one E-correct control), one Replay and
    one Generalize task, in the official release layout."""
    from memora_graph.bank import Bank

    bank, _ = small_bank
    videos = Bank(bank).manifest()["participants"]["P37"]["videos"]
    with Bank(bank).open("P37") as store:
        seg = store.rows("_baseline_segments_all", participant="P37")
    summary = max((s["summary"] for s in seg if s["summary"]), key=len).split(";")[0].strip()
    root = tmp_path_factory.mktemp("tasks")
    q = lambda qid, text, choices, answer, unans, **kw: {  # noqa: E731
        "question_id": qid, "question": text + IMPORTANT, "choices": choices + [OPTION_E], "correct_answer": answer,
        "is_multiple_choice": True, "qa_type": kw.get("qa_type", "ERecall"), "ground_truth": choices[0],
        "video_id": videos[0], "video_ids": videos[:1], "participant_id": "P37", "video_scope": videos[:1],
        "num_videos": 1, "is_unanswerable": unans, **({"source_participant": "p01", "target_participant": "p37"} if unans else {}),
    }
    questions = [
        q("p37_q0000", f"In video {videos[0]}, what did P37 do?", [summary, "juggled three oranges",
          "played the violin", "repaired a bicycle"], "A", False),
        q("p37_q0001", "When P37 bakes sourdough, which starter do they feed first?",
          ["rye starter", "wheat starter", "spelt starter", "no starter"], "E", True, qa_type="SPref"),
    ]
    (root / "eam_qa" / "questions").mkdir(parents=True)
    (root / "eam_qa" / "questions" / "p37.json").write_text(json.dumps({"questions": questions, "metadata": {}}))
    step = lambda i, n, v, o: {"narration_id": f"{videos[0]}_{i}", "narration": n, "verb": v, "noun": o,  # noqa: E731
                               "start_time": f"00:00:0{i}.00", "end_time": f"00:00:0{i}.50"}
    replay = [{"task_id": "plan_P37_test_000", "participant_id": "P37", "video_id": videos[0],
               "task_type": "cleanup_organization", "task_query": "Help P37 wash the plate.",
               "ground_truth_steps": [step(1, "pick up plate", "pick-up", "plate"), step(2, "wash plate", "wash", "plate")],
               "num_steps": 2, "time_span_seconds": 2.0, "primary_objects": ["plate"], "primary_verbs": ["wash"]}]
    generalize = [{"task_id": "generalize_novel_P37_test", "task_type": "fully_novel", "video_id": videos[0],
                   "participant_id": "P37", "task_query": "Help P37 rinse the cup.",
                   "ground_truth_steps": ["Pick up the cup from the counter.", "Rinse the cup under the tap at the sink.",
                                          "Place the cup on the drying rack."]}]
    for folder, data in (("replay", replay), ("generalize", generalize)):
        (root / "planning" / "suites" / folder).mkdir(parents=True)
        (root / "planning" / "suites" / folder / "p37.json").write_text(json.dumps(data))
    return root

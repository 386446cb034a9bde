"""The official-format loader: the bundled calibration files, round trips, and malformed files."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from memora_graph.bench.tasks import (
    OPTION_E, EamQuestion, load_eam_qa_file, load_generalize_file, load_replay_file, load_suite, write_suite,
)
from memora_graph.errors import DataError
from memora_graph.paths import calibration_dir


@pytest.fixture(scope="module")
def calibration():
    return load_suite()


def test_calibration_counts_match_the_readme(calibration):
    expected = {  # README table: questions (answerable + E-correct), replay, generalize
        "P01": (122, 30, 12, 12), "P02": (172, 43, 10, 10), "P03": (145, 36, 12, 10), "P04": (158, 40, 10, 10),
    }
    assert sorted(calibration.participants) == sorted(expected)
    for pid, (ans, unans, replay, gen) in expected.items():
        entry = calibration.participants[pid]
        qs = entry.eam_qa.questions
        assert sum(not q.is_unanswerable for q in qs) == ans
        assert sum(q.is_unanswerable for q in qs) == unans
        assert len(entry.replay) == replay
        assert len(entry.generalize) == gen
    p01 = [q for q in calibration.participants["P01"].eam_qa.questions if not q.is_unanswerable]
    assert sum(q.qa_type == "SRoutine" for q in p01) == 31
    assert sum(t.num_steps for t in calibration.participants["P01"].replay) == 104


def test_calibration_records_are_typed(calibration):
    q = calibration.participants["P01"].eam_qa.questions[0]
    assert q.question_id == "p01_q0000" and q.correct_answer == "B" and q.choices[4] == OPTION_E
    controls = [q for q in calibration.questions() if q.is_unanswerable]
    assert controls and all(q.correct_answer == "E" and q.source_participant and q.target_participant for q in controls)
    grounded = [s for t in calibration.replay_tasks() for s in t.ground_truth_steps if s.matched_object]
    assert grounded and all(s.enriched_narration for s in grounded)
    transfer = [t for t in calibration.generalize_tasks() if t.task_type == "transfer"]
    assert len(transfer) == 24 and all(t.source_action and t.target_object for t in transfer)


def test_participant_filter_and_unknown_participant(tmp_path):
    suite = load_suite(calibration_dir(), ["p02"])
    assert list(suite.participants) == ["P02"]
    with pytest.raises(DataError, match="P09"):
        load_suite(calibration_dir(), ["P09"])
    with pytest.raises(DataError, match="not a MEMORA-Bench release"):
        load_suite(tmp_path)


def test_write_then_load_round_trip_is_lossless(calibration, tmp_path):
    write_suite(calibration, tmp_path)
    again = load_suite(tmp_path)
    for pid, entry in calibration.participants.items():
        other = again.participants[pid]
        assert [q.model_dump() for q in other.eam_qa.questions] == [q.model_dump() for q in entry.eam_qa.questions]
        assert other.eam_qa.metadata == entry.eam_qa.metadata
        assert [t.model_dump() for t in other.replay] == [t.model_dump() for t in entry.replay]
        assert [t.model_dump() for t in other.generalize] == [t.model_dump() for t in entry.generalize]
    # the release's byte layout: 2-space indent, trailing newline, same keys in the same order
    original = json.loads((calibration_dir() / "planning/suites/replay/p02.json").read_text())
    written = json.loads((tmp_path / "planning/suites/replay/p02.json").read_text())
    assert written == original
    assert (tmp_path / "eam_qa/questions/p01.json").read_text().endswith("}\n")


def test_answering_view_hides_key_ground_truth_provenance_and_audit():
    q = EamQuestion(
        question_id="p01_q0001", question="Where?", choices=["a", "b", "c", "d", OPTION_E], correct_answer="B",
        qa_type="SPref", ground_truth="b", video_id="P01_102", video_ids=["P01_102"], participant_id="P01",
        video_scope=["P01_102"], num_videos=1, is_unanswerable=False, reasoning_depth=2, audit={"count": 5},
    )
    view = q.answering_view()
    for hidden in ("correct_answer", "ground_truth", "audit", "is_unanswerable", "source_participant", "reasoning_depth"):
        assert hidden not in view
    assert view["choices"][4] == OPTION_E and view["question"] == "Where?"


# ---- malformed files: the error names the file, the item and the field -----------------------

def _eam(tmp_path: Path, mutate, name: str = "p01.json") -> Path:
    data = json.loads((calibration_dir() / "eam_qa/questions/p01.json").read_text())
    mutate(data)
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("mutate, index, field", [
    (lambda d: d["questions"][3].__setitem__("choices", ["a", "b", "c", "d"]), 3, "choices"),
    (lambda d: d["questions"][5]["choices"].__setitem__(4, "None of the above"), 5, "option E"),
    (lambda d: d["questions"][7].__setitem__("qa_type", "ELoc"), 7, "qa_type"),
    (lambda d: d["questions"][2].pop("video_ids"), 2, "video_ids"),
    (lambda d: d["questions"][4].__setitem__("correct_answer", "F"), 4, "correct_answer"),
    (lambda d: d["questions"][6].__setitem__("correct_answer", "E"), 6, "is_unanswerable false"),
])
def test_malformed_question_names_file_item_and_field(tmp_path, mutate, index, field):
    path = _eam(tmp_path, mutate)
    with pytest.raises(DataError) as err:
        load_eam_qa_file(path)
    msg = str(err.value)
    assert str(path) in msg
    assert f"questions[{index}]" in msg and f"p01_q{index:04d}" in msg
    assert field in msg


def test_control_without_e_or_donor_is_refused(tmp_path):
    data = json.loads((calibration_dir() / "eam_qa/questions/p01.json").read_text())
    i = next(i for i, q in enumerate(data["questions"]) if q["is_unanswerable"])
    bad = copy.deepcopy(data)
    bad["questions"][i]["correct_answer"] = "A"
    (tmp_path / "p01.json").write_text(json.dumps(bad))
    with pytest.raises(DataError, match=rf"questions\[{i}\].*must answer 'E'"):
        load_eam_qa_file(tmp_path / "p01.json")
    bad = copy.deepcopy(data)
    del bad["questions"][i]["source_participant"]
    (tmp_path / "p01.json").write_text(json.dumps(bad))
    with pytest.raises(DataError, match="source_participant"):
        load_eam_qa_file(tmp_path / "p01.json")


def test_duplicate_ids_wrong_participant_and_bad_json(tmp_path):
    path = _eam(tmp_path, lambda d: d["questions"][9].__setitem__("question_id", "p01_q0000"))
    with pytest.raises(DataError, match=r"questions\[9\].*duplicate question_id \(first at questions\[0\]\)"):
        load_eam_qa_file(path)
    path = _eam(tmp_path, lambda d: None, name="p02.json")  # P01's items in p02.json
    with pytest.raises(DataError, match=r"p02.json: questions\[0\].*'P01' does not belong"):
        load_eam_qa_file(path)
    broken = tmp_path / "p03.json"
    broken.write_text('{"questions": [ {"question_id": }')
    with pytest.raises(DataError, match=r"p03.json: not valid JSON \(line 1"):
        load_eam_qa_file(broken)
    with pytest.raises(DataError, match="file not found"):
        load_eam_qa_file(tmp_path / "p99.json")


def test_malformed_planning_tasks(tmp_path):
    replay = json.loads((calibration_dir() / "planning/suites/replay/p01.json").read_text())
    replay[2]["num_steps"] = 3
    (tmp_path / "p01.json").write_text(json.dumps(replay))
    with pytest.raises(DataError, match=r"p01.json: tasks\[2\] \(task_id 'plan_P01_104_009'\).*num_steps"):
        load_replay_file(tmp_path / "p01.json")
    replay = json.loads((calibration_dir() / "planning/suites/replay/p01.json").read_text())
    replay[0]["ground_truth_steps"][1]["start_time"] = "75.2"
    (tmp_path / "p01.json").write_text(json.dumps(replay))
    with pytest.raises(DataError, match=r"tasks\[0\].*ground_truth_steps.1.*HH:MM:SS"):
        load_replay_file(tmp_path / "p01.json")
    gen = json.loads((calibration_dir() / "planning/suites/generalize/p01.json").read_text())
    del gen[1]["target_object"]
    (tmp_path / "g.json").write_text(json.dumps(gen))
    with pytest.raises(DataError, match=r"tasks\[1\] \(task_id 'generalize_transfer_P01_cutting_garlic'\).*target_object"):
        load_generalize_file(tmp_path / "g.json")
    gen = json.loads((calibration_dir() / "planning/suites/generalize/p01.json").read_text())
    gen[0]["task_id"] = "plan_P01_105_001"
    (tmp_path / "g.json").write_text(json.dumps(gen))
    with pytest.raises(DataError, match="starts with 'generalize_'"):
        load_generalize_file(tmp_path / "g.json")


def test_release_folder_with_a_bad_file_names_that_file(tmp_path):
    write_suite(load_suite(calibration_dir(), ["P03"]), tmp_path)
    path = tmp_path / "planning/suites/generalize/p03.json"
    data = json.loads(path.read_text())
    data[4]["ground_truth_steps"] = []
    path.write_text(json.dumps(data))
    with pytest.raises(DataError) as err:
        load_suite(tmp_path)
    assert "generalize/p03.json: tasks[4]" in str(err.value) and "ground_truth_steps" in str(err.value)

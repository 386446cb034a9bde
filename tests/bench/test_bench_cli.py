"""`memora bench generate` and `memora bench validate` through click's CliRunner."""

from __future__ import annotations

import json

from click.testing import CliRunner

from memora_graph.cli.bench import bench_group
from memora_graph.bench.tasks import load_suite
from memora_graph.paths import calibration_dir


def _row(output: str, name: str) -> list[str]:
    return next(line.split() for line in output.splitlines() if line.startswith(name + " "))


def test_validate_reproduces_the_calibration_counts():
    result = CliRunner().invoke(bench_group, ["validate", str(calibration_dir())])
    assert result.exit_code == 0, result.output
    # participant, questions, answerable, E-correct, SPref, SHabit, SRoutine, ERecall, replay, steps, generalize
    assert _row(result.output, "P01") == ["P01", "152", "122", "30", "35+7", "34+7", "31+12", "22+4", "12", "104", "12"]
    assert _row(result.output, "P04") == ["P04", "198", "158", "40", "41+10", "38+10", "46+13", "33+7", "10", "90", "10"]
    assert _row(result.output, "total")[:4] == ["total", "746", "597", "149"]
    assert "2,212 answerable + 551" in result.output and "207 Replay; 153 Generalize" in result.output


def test_validate_json_and_participant_filter():
    result = CliRunner().invoke(bench_group, ["validate", str(calibration_dir()), "--participants", "P02", "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert [p["participant_id"] for p in data["participants"]] == ["P02"]
    assert data["total"]["e_correct"] == 43 and data["total"]["replay_by_type"]["cleanup_organization"] == 4


def test_validate_reports_a_malformed_file_and_metadata_mismatch(tmp_path):
    src = json.loads((calibration_dir() / "eam_qa/questions/p01.json").read_text())
    folder = tmp_path / "eam_qa" / "questions"
    folder.mkdir(parents=True)
    src["metadata"]["n"] = 999
    (folder / "p01.json").write_text(json.dumps(src))
    result = CliRunner().invoke(bench_group, ["validate", str(tmp_path)])
    assert result.exit_code == 1
    assert "metadata.n is 999 but 122" in result.output
    src["questions"][12]["choices"] = ["only one"]
    (folder / "p01.json").write_text(json.dumps(src))
    result = CliRunner().invoke(bench_group, ["validate", str(tmp_path)])
    assert result.exit_code == 1
    assert "p01.json: questions[12] (question_id 'p01_q0012')" in result.output and "choices" in result.output


def test_generate_writes_a_valid_release_and_prints_the_table(tmp_path):
    out = tmp_path / "suite"
    result = CliRunner().invoke(bench_group, ["generate", "--out", str(out), "--participants", "P23,P37",
                                              "--seed", "5", "--no-dedup"])
    assert result.exit_code == 0, result.output
    assert _row(result.output, "P23")[0] == "P23" and "Wrote" in result.output
    suite = load_suite(out)
    assert sorted(suite.participants) == ["P23", "P37"]
    manifest = json.loads((out / "generation.json").read_text())
    assert manifest["seed"] == 5 and manifest["participants"] == ["P23", "P37"]
    assert manifest["totals"]["answerable"] == sum(not q.is_unanswerable for q in suite.questions())
    check = CliRunner().invoke(bench_group, ["validate", str(out)])
    assert check.exit_code == 0, check.output
    assert _row(check.output, "P37") == _row(result.output, "P37")


def test_generate_unknown_participant_is_an_error(tmp_path):
    result = CliRunner().invoke(bench_group, ["generate", "--out", str(tmp_path), "--participants", "P99", "--no-dedup"])
    assert result.exit_code == 1
    assert "Error: no annotations for participant(s) P99" in result.output and "P01" in result.output


def test_help_has_examples():
    for cmd in ("generate", "validate"):
        result = CliRunner().invoke(bench_group, [cmd, "--help"])
        assert result.exit_code == 0 and "Examples:" in result.output and f"memora bench {cmd}" in result.output

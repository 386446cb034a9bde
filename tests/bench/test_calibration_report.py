"""The report's confidence section (ECE, coverage accuracy, the reliability diagram, abstention)
and `memora bench calibrate` on hand-made records with known outcomes."""

from __future__ import annotations

import json
import random

from click.testing import CliRunner

from memora_graph.agent.confidence import load_calibration
from memora_graph.bench.report import build_report, write_report
from memora_graph.cli import main


def _write(run, cond, recs):
    path = run / "records" / "eam_qa" / f"{cond}.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(r) + "\n" for r in recs))


def _records(n=300, seed=0):
    rng = random.Random(seed)
    out = []
    for i in range(n):
        conf = rng.random()
        gold = "E" if i % 5 == 0 else "B"
        right = rng.random() < conf  # calibrated by construction
        pred = gold if right else ("A" if gold != "A" else "C")
        reason = "; no record of the subject" if pred == "E" else "; supported"
        out.append({"item_id": f"q{i}", "question_id": f"q{i}", "qa_type": "SPref", "correct_answer": gold,
                    "predicted": pred, "participant": ["P01", "P02", "P04"][i % 3], "status": "ok", "tool_calls": [],
                    "time": {"total_s": 0.1}, "confidence": round(conf, 4), "final_text": f"preference/method{reason}",
                    "reader_features": {"margin": conf, "subject_found": 1.0, "best_letter": "B"}})
    return out


def test_report_shows_ece_coverage_and_the_reliability_diagram(tmp_path):
    recs = _records()
    _write(tmp_path, "memora_full", recs)
    paths = write_report(tmp_path)
    rep = json.loads(paths["json"].read_text())
    cal = rep["eam_qa"]["calibration"]["conditions"]["memora_full"]["all"]
    assert cal["n"] == 300 and cal["ece"] < 0.12  # calibrated records: a small error
    hand = sum(b["n"] / 300 * abs(b["accuracy"] - b["confidence"]) for b in cal["reliability"])
    assert abs(cal["ece"] - hand) < 1e-9
    cov = cal["coverage_accuracy"]
    assert cov["50"] > cov["80"] > cov["100"]  # the most confident answers are the most often right
    md = paths["markdown"].read_text()
    assert "ECE" in md and "acc % (50%)" in md and "reliability.png" in md
    assert paths["reliability"].exists() and paths["reliability"].stat().st_size > 5000
    ab = rep["eam_qa"]["abstention"]["memora_full"]
    ans = [r for r in recs if r["correct_answer"] != "E"]
    assert ab["answerable_abstained"] == sum(r["predicted"] == "E" for r in ans) / len(ans)
    assert set(ab["abstain_reasons"]) <= {"no record of the subject"}


def test_records_without_a_confidence_have_no_calibration_section(tmp_path):
    recs = [{k: v for k, v in r.items() if k != "confidence"} for r in _records(20)]
    _write(tmp_path, "memora_full", recs)
    assert "calibration" not in build_report(tmp_path)["eam_qa"]


def test_calibrate_command_fits_on_the_chosen_participants_only(tmp_path):
    rng = random.Random(1)
    recs = []
    for i, r in enumerate(_records(600, seed=1)):  # the best option (B) is right as often as its margin says
        margin = r["reader_features"]["margin"]
        recs.append({**r, "correct_answer": "E" if i % 5 == 0 else ("B" if rng.random() < margin else "C")})
    _write(tmp_path, "memora_full", recs)
    out = tmp_path / "calibration.json"
    res = CliRunner().invoke(main, ["bench", "calibrate", str(tmp_path), "--participants", "P01,P02",
                                    "--conditions", "memora_full", "--out", str(out)])
    assert res.exit_code == 0, res.output
    cal = load_calibration(out)
    assert cal.fitted_on["participants"] == ["P01", "P02"] and cal.fitted_on["n"] == 400  # P04 left out
    lo, hi = (cal.probabilities({"margin": m, "subject_found": 1.0})["best"] for m in (0.1, 0.9))
    assert hi > lo + 0.3
    empty = CliRunner().invoke(main, ["bench", "calibrate", str(tmp_path), "--participants", "P03",
                                      "--out", str(tmp_path / "x.json")])
    assert empty.exit_code != 0 and "features" in empty.output and not (tmp_path / "x.json").exists()

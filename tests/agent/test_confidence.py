"""The reader's confidence and subject detection: compounds and synonyms are found in memory, the
package's calibration loads and is monotone in the evidence, E is decided by the threshold on the
probability, a fit recovers what the outcomes depend on, and the evidence budget reads the first
K records of the calls in turn."""

from __future__ import annotations

import json
import random

import pytest

from memora_graph.agent.confidence import CALIBRATION_FILE, Calibration, load_calibration
from memora_graph.agent.evidence import budgeted_events, object_classes
from memora_graph.agent.reading import Event, parse_question, score, subject_mentions
from memora_graph.bench.calibration import best_threshold, ece, fit, selective_accuracy
from memora_graph.errors import MemoraError
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.baselines.flat1d import FlatHit, FlatSearchResult

CHOICES = ["wipes it with a cloth", "washes it with the sponge", "puts it in the drawer", "throws it in the bin"]


@pytest.fixture(scope="module")
def lex():
    return Lexicon.load()


def _log(video: str, t: float, verb: str, *nouns: str) -> Event:
    return Event(video, t, verb, tuple(nouns), (f"{video}#t{int(t)}",), text=f"{verb} {' '.join(nouns)}")


def test_memory_object_names_are_read_as_their_class(lex):
    # a class key stays itself; a compound in memory's order is read in English order
    assert object_classes("board:chopping", lex) == ["board:chopping"]
    assert object_classes("liquid:washing", lex) == ["liquid:washing"]
    assert object_classes("towel_kitchen", lex) == ["towel"] or object_classes("towel:kitchen", lex) == ["towel:kitchen"]
    assert lex.noun_classes("liquid washing") == ["liquid"]  # what the words alone gave before


@pytest.mark.parametrize("question, memory_noun", [
    ("How does P01 usually clean the chopping board?", "board:chopping"),   # compound, English order
    ("How does P01 usually clean the cutting board?", "board:chopping"),    # synonym of the compound
    ("What does P01 do with the washing-up liquid after using it?", "liquid:washing"),
    ("How does P01 usually clean the chopping board?", "board"),            # memory holds the head class only
    ("Where does P01 keep the frying pan?", "pan"),                         # synonym ("frying pan" -> pan)
])
def test_the_subject_is_found_at_class_and_compound_level(lex, question, memory_noun):
    intent = parse_question(question, lex)
    events = [_log("P01_01", 10.0 + i, v, memory_noun) for i, v in enumerate(["take", "wash", "put"])]
    assert subject_mentions(set(intent.subject_nouns), events) == 3
    d = score(question, CHOICES, events, lex)
    assert d.reason != "no record of the subject"


def test_a_subject_memory_never_holds_is_no_record(lex):
    question = "How does P01 usually clean the chopping board?"
    events = [_log("P01_01", 10.0 + i, v, "cup") for i, v in enumerate(["take", "wash", "put"])]
    d = score(question, CHOICES, events, lex)
    assert d.letter == "E" and d.reason == "no record of the subject" and d.features["subject_found"] == 0.0


def _cal(threshold: float) -> Calibration:
    return Calibration(["best", "margin"], [0.0, 0.0], [1.0, 1.0], {"best": [2.0, 3.0], "E": [-1.0, -1.0]},
                       {"best": 0.0, "E": 0.0}, threshold)


def test_the_e_decision_is_the_probability_against_the_threshold(lex):
    question = "How does P01 usually clean the cup?"
    events = [_log("P01_01", 10.0 + 2 * i, v, "cup", "sponge") for i, v in enumerate(["take", "wash", "put"])] * 3
    low, high = score(question, CHOICES, events, lex, calibration=_cal(0.05)), \
        score(question, CHOICES, events, lex, calibration=_cal(0.999))
    assert low.features == high.features and low.p_best == high.p_best
    assert low.letter == "B" and low.probability == low.p_best  # washes it with the sponge
    assert high.letter == "E" and high.probability == high.p_e and "too weak" in high.reason
    assert abs(low.p_best + low.p_e + (1 - low.p_best - low.p_e) - 1) < 1e-9


def test_the_package_calibration_loads_and_is_monotone():
    cal = load_calibration()
    assert cal is not None, f"{CALIBRATION_FILE} is missing: refit with `memora bench calibrate`"
    assert set(cal.fitted_on["participants"]) <= {"P01", "P02", "P03"}  # P04 held out
    assert 0.05 <= cal.threshold <= 0.95
    base = {f: m for f, m in zip(cal.features, cal.mean)}
    ps = [cal.probabilities({**base, "margin": m, "best": base["best"] + m})["best"] for m in (0.0, 0.5, 1.0, 2.0)]
    assert ps == sorted(ps) and ps[-1] > ps[0]  # a clearer, stronger best option is likelier right
    # evidence weak in classes and in meaning: likelier not in memory; a widened situation: less sure
    gone = cal.probabilities({**base, "best": base["best"] - 1.0, "best_class": 0.1, "best_sim": 0.3})
    assert gone["E"] > cal.probabilities(base)["E"]
    assert cal.probabilities({**base, "relaxed_2": 1.0})["best"] < cal.probabilities(base)["best"]
    for p in (cal.probabilities(base), gone):
        assert abs(sum(p.values()) - 1) < 1e-9 and all(0 < v < 1 for v in p.values())


def test_a_damaged_calibration_file_is_named(tmp_path):
    bad = tmp_path / "calibration.json"
    bad.write_text('{"features": ["best"]}')
    with pytest.raises(MemoraError, match="calibration.json"):
        load_calibration(bad)
    assert load_calibration(tmp_path / "absent.json") is None


def test_fit_learns_what_the_outcome_depends_on():
    rng = random.Random(3)
    records = []
    for i in range(600):
        margin, found = rng.random(), float(rng.random() < 0.8)
        p_best = 0.1 + 0.8 * margin if found else 0.05
        u = rng.random()
        gold = "A" if u < p_best else ("E" if u < p_best + (0.6 if not found else 0.1) else "C")
        records.append({"status": "ok", "participant": "P01", "correct_answer": gold,
                        "reader_features": {"margin": margin, "subject_found": found, "best_letter": "A"}})
    cal = fit(records, fitted_on={"participants": ["P01"]})
    lo, hi = (cal.probabilities({"margin": m, "subject_found": 1.0})["best"] for m in (0.1, 0.9))
    assert hi - lo > 0.4 and abs(hi - 0.82) < 0.1
    assert cal.probabilities({"margin": 0.5, "subject_found": 0.0})["E"] > 0.4
    restored = Calibration.from_json(json.loads(json.dumps(cal.to_json())))
    assert restored.probabilities({"margin": 0.3, "subject_found": 1.0}) == cal.probabilities({"margin": 0.3, "subject_found": 1.0})


def test_threshold_ece_and_coverage_by_hand():
    # best right (0) when p high, E right (1) when p low: the best cut lies between 0.3 and 0.7
    t = best_threshold([0.9, 0.8, 0.7, 0.3, 0.2], [0, 0, 0, 1, 1])
    assert 0.3 < t <= 0.7
    assert best_threshold([0.9, 0.2], [0, 0], forced=[False, True]) <= 0.9
    assert ece([0.9, 0.9, 0.1, 0.1], [True, False, False, False]) == pytest.approx(0.5 * 0.4 + 0.5 * 0.1)
    assert selective_accuracy([0.9, 0.8, 0.2, 0.1], [True, True, False, True], 0.5) == 1.0
    assert selective_accuracy([0.9, 0.8, 0.2, 0.1], [True, True, False, True], 1.0) == 0.75


def test_the_evidence_budget_reads_the_calls_records_in_turn(lex):
    def search(*names):
        return FlatSearchResult(query="x", results=[
            FlatHit(kind="activity", video="P01_01", time=float(i), text=f"take {n}", similarity=0.5)
            for i, n in enumerate(names)])

    a, b = search("cup", "plate", "bowl"), search("knife", "spoon")
    read = lambda k: [e.nouns[0] for e in budgeted_events([a, b], lex, k)]
    assert read(1) == ["cup"]
    assert read(3) == ["cup", "knife", "plate"]
    assert read(None) == ["cup", "plate", "bowl", "knife", "spoon"] and sorted(read(100)) == sorted(read(None))


def test_the_offline_policy_answers_with_the_package_calibration_unless_told_not_to():
    from memora_graph.agent.offline import OfflinePolicy

    assert OfflinePolicy().calibration is not None
    assert OfflinePolicy(calibration="none").calibration is None
    with pytest.raises(MemoraError, match="evidence_budget"):
        OfflinePolicy(evidence_budget=0)

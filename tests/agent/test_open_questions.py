"""Open questions (no choices): the parser per kind on wordings no generator template uses, typed
answers on a small real bank checked against the annotations, "not in memory" with its reason,
the open-question generator and scorer, and the calibration file."""

from __future__ import annotations

import json
import math
import re

import pytest
from click.testing import CliRunner

from memora_graph.agent.ask import ask
from memora_graph.agent.query import OpenAnswer
from memora_graph.agent.query.answer import answer_open
from memora_graph.agent.open_calibration import CALIBRATION_FILE, ece, fit, load, probability
from memora_graph.agent.query.lexical import parse_open
from memora_graph.bench.behaviour import PUT_VERB_KEYS, build_behaviours
from memora_graph.bench.generate_scoped import SCOPED_SPLITS
from memora_graph.bench.generate_open import (
    GENERAL, OPEN_KINDS, SPLITS, TEMPLATES, OpenItem, count_ok, generate_open, score_item,
)
from memora_graph.cli import main
from memora_graph.perceive.annotations import load_annotations
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve import MemoryView


@pytest.fixture(scope="module")
def lex():
    return Lexicon.load()


@pytest.fixture(scope="module")
def cohort():
    return build_behaviours(load_annotations(participants=["P09", "P37", "P01"]))


# wordings written for this test only: none is a generator template
PARSED = [
    ("Whereabouts does P07 normally stash the chopping board?", "place", None, "board:chopping", "usual"),
    ("Where did the cutting board get put most recently by P07?", "place", None, "board:chopping", "last"),
    ("Which surface did P07 last leave the frying pan on?", "place", None, "pan", "last"),
    ("From where does P07 usually grab the milk?", "place", "take", "milk", "usual"),
    ("Which of P07's recordings shows them slicing the onion for the first time?", "time", "cut", "onion", "first"),
    ("In what recording did P07 most recently rinse a mug?", "time", "wash", "cup", "last"),
    ("At what point in the footage did P07 first switch on the kettle?", "time", "turn-on", "kettle", "first"),
    ("How often has P07 closed the fridge door?", "count", "close", "fridge", "usual"),
    ("What's the number of occasions on which P07 opened a drawer?", "count", "open", "drawer", "usual"),
    ("Did P07 at some point crack an egg?", "yesno", None, "egg", "usual"),
    ("Has P07 ever been seen drying a plate?", "yesno", "dry", "plate", "usual"),
    ("Once P07 switches off the tap, what do they generally go on to do?", "next", "turn-off", "tap", "usual"),
    ("Whenever P07 has rinsed the sponge, what comes afterwards?", "next", "wash", "sponge", "usual"),
    ("What sequence of steps does P07 go through to wash up a pan?", "routine", "wash", "pan", "usual"),
    ("What condition was the fridge in at 1:05 in P07_101?", "state", None, "fridge", "usual"),
    ("What was P07 up to in P07_102 around the 90 second mark?", "activity", None, None, "usual"),
    # a statement, then the question; passives with and without the agent
    ("P07 has just rinsed the colander. What are they likely to do now?", "next", "wash", "colander", "usual"),
    ("In total, how many times was the oven door opened?", "count", "open", "oven", "usual"),
    ("When was the kettle most recently filled by P07?", "time", "fill", "kettle", "last"),
]


@pytest.mark.parametrize("question, kind, verb, noun, order", PARSED)
def test_the_parser_reads_what_is_asked_on_unseen_wordings(lex, question, kind, verb, noun, order):
    q = parse_open(question, lex, "P07")
    assert q.kind == kind, q
    if verb is not None:
        assert q.verb == verb, q
    if noun is not None:
        assert noun in q.nouns, q
    if kind in ("place", "time"):
        assert q.order == order, q
    assert q.about_person == ("P07" in question)


def test_the_parser_reads_times_videos_and_units(lex):
    q = parse_open("What state was the kettle in at 2:30 in P07_103?", lex)
    assert (q.kind, q.videos, q.time) == ("state", ["P07_103"], 150)
    assert parse_open("In how many different videos did P07 wash the pan?", lex).unit == "videos"
    assert parse_open("How many times did P07 wash the pan?", lex).unit == "times"
    assert parse_open("Where did P05 put the knife?", lex, "P07").persons == ["P05"]


@pytest.mark.parametrize("question", [
    "What is the capital of Italy?", "How many legs does an insect have?", "Who invented the toaster?",
    "At what temperature does sugar caramelise?", "Is a courgette a fruit?", "Where do pineapples grow?",
    "How is butter made?", "Why does milk go sour?", "How many millilitres are in a litre?",
])
def test_general_knowledge_is_general_whatever_kitchen_words_it_uses(lex, question):
    assert parse_open(question, lex, "P07").kind == "general"


def test_a_memory_question_without_a_person_stays_a_memory_question(lex):
    for question, kind in [("Where is the kettle kept?", "place"), ("When was the fridge last opened?", "time"),
                           ("How many times was the tap turned on?", "count")]:
        assert parse_open(question, lex).kind == kind


# -- typed answers on a real bank, checked against the annotations -------------------------------

def test_typed_answers_match_the_annotations(small_bank, cohort, lex):
    bank, _ = small_bank
    b = cohort["P37"]
    steps = [s for v in b.videos for s in b.steps_by_video[v]]
    counts = {}
    for s in steps:
        counts.setdefault(s.action, []).append(s)
    action, rows = max(((a, r) for a, r in counts.items() if a.noun != "hand" and len({s.video_id for s in r}) >= 2),
                       key=lambda ar: len(ar[1]))
    verb, obj = action.verb.replace("-", " "), action.noun.replace("_", " ")
    with MemoryView.open(bank, "P37") as view:
        n = answer_open(view, "P37", f"How many times did P37 {verb} the {obj}?", lex)
        assert n.kind == "count" and count_ok(n.count, len(rows)), (n.answer, len(rows))
        assert len(n.records) == min(len(rows), 20) and all(r.segment_id in n.evidence for r in n.records)
        last = answer_open(view, "P37", f"In which video did P37 last {verb} the {obj}?", lex)
        assert last.kind == "time" and last.moment.video == rows[-1].video_id
        first = answer_open(view, "P37", f"When did P37 {verb} the {obj} for the first time?", lex)
        assert first.moment.video == rows[0].video_id
        yes = answer_open(view, "P37", f"Has P37 ever {verb}ed the {obj}?".replace("eed", "ed"), lex)
        assert yes.kind == "yesno" and yes.yes is True and yes.evidence
        puts = [s for s in steps if s.place and s.action.verb in PUT_VERB_KEYS and s.action.noun != s.place]
        noun = puts[-1].action.noun
        placed = answer_open(view, "P37", f"Where did P37 last put the {noun.replace('_', ' ')}?", lex)
        last_put = [s for s in puts if s.action.noun == noun][-1]
        assert placed.kind == "place" and placed.place.place == last_put.place and placed.place.video == last_put.video_id
        for e in placed.evidence + n.evidence:  # evidence ids are the bank's segments
            assert e.split("#")[0] in view.videos


def test_answers_count_in_the_right_number(small_bank, cohort, lex):
    """An action seen once, in one video, is "1 time", "in 1 video", "1 record", and an object put
    once has "1 placement": no "1 videos" or "1 placements" in an answer or its detail."""
    bank, _ = small_bank
    b = cohort["P37"]
    steps = [s for v in b.videos for s in b.steps_by_video[v]]
    by_action: dict = {}
    for s in steps:
        by_action.setdefault(s.action, []).append(s)
    once = [a for a, r in by_action.items() if len(r) == 1 and a.noun not in ("hand", "")]
    puts = [s for s in steps if s.place and s.action.verb in PUT_VERB_KEYS and s.action.noun != s.place]
    put_once = [n for n in {s.action.noun for s in puts} if sum(s.action.noun == n for s in puts) == 1]
    assert once and put_once, "P37 has an action seen once and an object put once"
    texts = []
    with MemoryView.open(bank, "P37") as view:
        for action in once[:5]:
            verb, obj = action.verb.replace("-", " "), action.noun.replace("_", " ")
            for q in (f"How many times did P37 {verb} the {obj}?", f"In which video did P37 last {verb} the {obj}?",
                      f"Has P37 ever {verb}ed the {obj}?".replace("eed", "ed")):
                a = answer_open(view, "P37", q, lex)
                texts += [a.answer, a.detail or ""]
        for noun in sorted(put_once)[:5]:
            a = answer_open(view, "P37", f"Where did P37 last put the {noun.replace('_', ' ')}?", lex)
            texts += [a.answer, a.detail or ""]
    joined = "\n".join(texts)
    assert re.search(r"\b1 (video|time|record|placement)\b", joined), joined  # the singular is used
    assert not re.search(r"\b1 (videos|times|records|placements)\b", joined), joined


def test_not_in_memory_says_why(small_bank, lex):
    bank, _ = small_bank
    with MemoryView.open(bank, "P37") as view:
        gk = answer_open(view, "P37", "What is the capital of France?", lex)
        assert (gk.kind, gk.in_memory, gk.reason) == ("not_in_memory", False, "general_knowledge")
        tool = answer_open(view, "P37", "Has P37 ever used a chainsaw?", lex)
        assert (tool.in_memory, tool.reason) == (False, "absent_subject") and "chainsaw" in tool.detail
        other = answer_open(view, "P37", "Where did P09 last put the knife?", lex)
        assert (other.in_memory, other.reason) == (False, "absent_subject") and "P09" in other.detail
        video = answer_open(view, "P37", "What did P37 do in video P37_999?", lex)
        assert video.reason == "absent_subject"
    nouns = {n for s in _log(bank, "P37", lex) for n in s.nouns}
    absent = next(n for n in ("pineapple", "mushroom", "avocado", "coconut") if n not in nouns)
    r = ask(bank, "P37", f"Where does P37 keep the {absent}?")
    assert r.answer == "not in memory" and r.typed.reason == "absent_subject" and 0 < r.confidence < 1


def _log(bank, pid, lex):
    from memora_graph.agent.query.log import action_log

    with MemoryView.open(bank, pid) as view:
        return action_log(view, lex)


def test_ask_prints_the_typed_answer_and_its_confidence(small_bank):
    bank, _ = small_bank
    runner = CliRunner()
    r = runner.invoke(main, ["ask", str(bank), "How many times did P37 open the fridge?", "--participant", "P37",
                             "--json"])
    assert r.exit_code == 0, r.output
    data = json.loads(r.output)
    typed = data["typed"]
    assert typed["kind"] == "count" and isinstance(typed["count"], int) and typed["records"]
    assert 0 < data["confidence"] < 1 and typed["evidence"]
    r = runner.invoke(main, ["ask", str(bank), "What is the capital of France?", "--participant", "P37"])
    assert r.exit_code == 0 and r.output.startswith("not in memory") and "general knowledge" in r.output
    assert "confidence" in r.output


# -- generator and scorer --------------------------------------------------------------------------

def test_the_generator_gives_every_kind_with_gold_from_the_annotations(cohort):
    others = {k: v for k, v in cohort.items() if k != "P01"}
    items = generate_open(cohort["P01"], others, seed=3)
    kinds = {i.kind for i in items}
    assert kinds == set(OPEN_KINDS), kinds
    b = cohort["P01"]
    steps = [s for v in b.videos for s in b.steps_by_video[v]]
    for it in items:
        assert it.split in SPLITS + SCOPED_SPLITS and it.question.endswith((".", "?")) and "{" not in it.question
        if it.kind == "count":
            assert it.gold["count"] >= 2
        if it.kind == "place_last":
            assert any(s.place == it.gold["place"] for s in steps)
        if it.kind == "general":
            assert it.question in {q for s in SPLITS for q in GENERAL[s]}
    # the same seed gives the same questions
    assert [i.question for i in generate_open(cohort["P01"], others, seed=3)] == [i.question for i in items]
    assert all(set(TEMPLATES[k]) == set(SPLITS) for k in TEMPLATES)


def test_the_scorer_scores_by_type():
    def item(gold):
        return OpenItem(question_id="x", participant_id="P01", kind="k", question="q", template="t", split="dev",
                        gold=gold)

    base = {"question": "q", "participant": "P01", "asked": "count", "in_memory": True, "answer": ""}
    assert score_item(item({"count": 10}), OpenAnswer(**base, kind="count", count=12))["correct"]
    assert not score_item(item({"count": 10}), OpenAnswer(**base, kind="count", count=13))["correct"]
    assert count_ok(1, 2) and not count_ok(4, 2)
    nim = OpenAnswer(**{**base, "in_memory": False}, kind="not_in_memory", reason="general_knowledge")
    assert score_item(item({"not_in_memory": "general_knowledge"}), nim) == {"correct": True, "reason_ok": True}
    assert score_item(item({"not_in_memory": "absent_subject"}), nim) == {"correct": True, "reason_ok": False}
    assert not score_item(item({"yes": False}), nim)["correct"]


def test_bench_open_scores_a_bank_and_generate_writes_open_questions(small_bank, tmp_path):
    bank, _ = small_bank
    runner = CliRunner()
    r = runner.invoke(main, ["bench", "generate", "--out", str(tmp_path / "gen"), "--kind", "open",
                             "--participants", "P37"])
    assert r.exit_code == 0, r.output
    data = json.loads((tmp_path / "gen" / "open" / "p37.json").read_text())
    assert data["questions"] and {q["kind"] for q in data["questions"]} >= {"count", "general", "absent"}
    out = tmp_path / "open.json"
    r = runner.invoke(main, ["bench", "open", str(bank), "--participants", "P37", "--questions",
                             str(tmp_path / "gen" / "open"), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "ALL" in r.output and "ECE" in r.output
    result = json.loads(out.read_text())
    s = result["summary"]
    assert s["overall"]["accuracy"] >= 0.7, s
    for kind in ("general", "absent"):  # "not in memory" where memory cannot speak
        assert s["per_kind"][kind]["accuracy"] == 1.0, s["per_kind"][kind]
    r = runner.invoke(main, ["bench", "open", str(bank), "--participants", "P37", "--seed", "x"])
    assert r.exit_code != 0 and "seeds are integers" in r.output


# -- calibration -----------------------------------------------------------------------------------

def test_the_calibration_file_loads_with_its_provenance():
    data = load()
    assert CALIBRATION_FILE.exists()
    assert data["fitted_on"] == ["P01", "P02", "P03"] and "memora bench open" in data["command"]
    assert data["n"] > 100 and "kind=not_in_memory" in data["weights"]
    p = probability("count", {"log_support": math.log1p(8), "share": 1, "margin": 1, "exact": 1}, data["weights"])
    assert 0 < p < 1


def test_fit_and_ece_behave():
    rows = [("count", {"log_support": x / 10, "share": 1.0, "margin": 1.0, "exact": 1.0}) for x in range(40)]
    labels = [x >= 20 for x in range(40)]
    w = fit(rows, labels, l2=0.1)
    probs = [probability(k, f, w) for k, f in rows]
    assert probs[0] < 0.5 < probs[-1] and probs == sorted(probs)
    err, table = ece([0.9] * 10, [True] * 9 + [False])
    assert err == 0.0 and table[0]["n"] == 10
    err, _ = ece([1.0] * 4, [True, True, False, False])
    assert err == 0.5


def test_the_served_ask_tool_returns_the_typed_answer(small_bank):
    from memora_graph.serve.service import MemoryService

    bank, _ = small_bank
    with MemoryService(bank, "P37") as service:
        out = service.call("ask", {"question": "How many times did P37 open the fridge?"})
    assert out["typed"]["kind"] == "count" and out["typed"]["count"] == int(out["answer"].split()[0])
    assert 0 < out["confidence"] < 1 and out["evidence"]


def test_the_action_log_reads_each_step_by_its_own_words_when_wordings_repeat(lex):
    """The log parses each distinct step wording once: steps that share a narration but not their
    object or action still get their own classes, as parsing every step afresh gives them."""
    from memora_graph.agent.query.log import _step_classes, step_log
    from memora_graph.retrieve.steps import StepRows

    def seg(i, steps):
        return {"id": f"P07_101#t{i:04d}", "video": "P07_101", "t_start": 10.0 * i, "action_breakdown": json.dumps(steps)}

    segments = [
        seg(0, [{"narration": "put the knife in the drawer", "object": "knife", "action": "put", "timestamp": 1.0}]),
        seg(1, [{"narration": "put the knife in the drawer", "object": "spoon", "action": "put", "timestamp": 2.0},
                {"narration": "put the knife in the drawer", "object": "knife", "action": "take", "timestamp": 3.0}]),
        seg(2, [{"narration": "open the fridge", "object": "fridge", "action": "open", "timestamp": 0.5},
                {"narration": "put the knife in the drawer", "object": "knife", "action": "put", "timestamp": 4.0}]),
    ]
    seen: dict = {}
    shared = list(step_log(StepRows.build(segments), lex, seen))
    afresh = [_step_classes(s["narration"], s["object"], s["action"], lex)
              for g in segments for s in json.loads(g["action_breakdown"])]
    assert [(s.verb, s.objects, s.nouns, s.place) for s in shared] == afresh and len(seen) == 4
    assert [s.objects[0] for s in shared[:3]] == ["knife", "spoon", "knife"]
    assert shared[1].verb != shared[2].verb and [s.t for s in shared] == [1.0, 12.0, 13.0, 20.5, 24.0]

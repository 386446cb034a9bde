"""The typed query: the compositional parser on wordings no generator template uses, the query
model's own checks, the length cap, and answers on a real small bank (P09, P37) checked against
the annotations: scope, selector and relation combined, the person's own words, the counterfactual."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from memora_graph.agent.query import MAX_QUESTION, Query, QuestionError, parse, recall
from memora_graph.agent.query.answer import answer_question
from memora_graph.bench.behaviour import build_behaviours
from memora_graph.cli import main
from memora_graph.perceive.annotations import load_annotations
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve import MemoryView


@pytest.fixture(scope="module")
def lex():
    return Lexicon.load()


# (question, operation, scope fields, selector, relation): the parts read independently
PARTS = [
    ("So what was the very last thing I did in P07_102?", "list", {"videos": ["P07_102"]}, "last", None),
    ("In P07_102, what was my first action?", "list", {"videos": ["P07_102"]}, "first", None),
    ("What does P07 tend to do right before they put the pot down?", "previous", {}, "usual", "before"),
    ("Tell me how many times I opened the fridge during recording P07_103.", "count", {"videos": ["P07_103"]},
     "usual", None),
    ("Between 1:00 and 2:30 of P07_101, how often did I rinse a cup?", "count",
     {"videos": ["P07_101"], "start": 60.0, "end": 150.0}, "usual", None),
    ("In which of the videos did P07 open the fridge for the third time?", "which_video", {}, "nth", None),
    ("What did I get up to first thing in my second session?", "list", {"session": 2}, "first", None),
    ("What happened in P07_104?", "list", {"videos": ["P07_104"]}, "all", None),
    ("What do I keep doing while the tap is running?", "list", {}, "usual", "while"),
    ("What do I reach for instead of the knife?", "list", {}, "usual", "instead_of"),
    ("How long was P07_101?", "duration", {"videos": ["P07_101"]}, "usual", None),
    ("Was the fridge closed at 00:45 in P07_101?", "exists", {"videos": ["P07_101"], "at": 45.0}, "usual", None),
]


@pytest.mark.parametrize("question,op,scope,selector,relation", PARTS)
def test_parser_combines_scope_selector_relation_and_operation(lex, question, op, scope, selector, relation):
    q = parse(question, lex)
    assert q.operation == op, q.brief()
    got = q.scope.model_dump(exclude_defaults=True, exclude={"after", "before"})
    assert got == scope, q.brief()
    assert q.selector == selector, q.brief()
    assert q.relation == relation, q.brief()
    assert q.why_not() is None, q.why_not()


def test_an_event_scopes_the_question_s_own_action(lex):
    q = parse("Where did I put the knife after I cut the onion?", lex)
    assert q.operation == "where" and q.subject.objects == ["knife"] and q.relation is None
    assert q.scope.after is not None and q.scope.after.verb == "cut" and q.scope.after.objects == ["onion"]
    # the same event with no action of the question's own is the relation asked about
    q = parse("What do I normally do after I cut the onion?", lex)
    assert q.operation == "next" and q.relation == "after" and q.anchor.objects == ["onion"]


def test_a_question_naming_no_person_is_about_the_owner(lex):
    for text in ("Where is the kettle?", "Where are the plates?", "Is the fridge open now?"):
        q = parse(text, lex)
        assert not q.world and q.person is None, (text, q.brief())
    for text in ("Where do bananas grow?", "Is a tomato a fruit?", "What is the capital of France?"):
        assert parse(text, lex).world, text


def test_empty_and_too_long_questions_are_refused(lex):
    for text in ("", "   \n"):
        with pytest.raises(QuestionError, match="empty"):
            parse(text, lex)
    ok = ("Where did I put the knife? " * 100)[:MAX_QUESTION]
    assert parse(ok, lex).operation == "where"
    with pytest.raises(QuestionError, match="too long: 2,001 characters"):
        parse(ok + "x", lex)


def test_query_model_says_why_a_combination_makes_no_sense():
    assert "count" in Query(operation="count", subject={"verb": "open", "objects": ["fridge"]},
                            selector="last").why_not()
    assert "anchor" in Query(operation="list", relation="before").why_not()
    assert "ends before it starts" in Query(operation="list", scope={"start": 90, "end": 30}).why_not()
    with pytest.raises(ValueError):
        Query.model_validate({"operation": "fly"})
    with pytest.raises(ValueError):  # unknown fields are refused, not ignored
        Query.model_validate({"operation": "count", "colour": "red"})
    schema = Query.model_json_schema()
    assert set(schema["properties"]["operation"]["enum"]) == {"where", "when", "which_video", "count", "exists", "list",
                                                             "next", "previous", "steps", "state", "duration"}


# -- answers from a real bank ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def p37(small_bank):
    with MemoryView.open(small_bank[0], "P37") as view:
        yield view


@pytest.fixture(scope="module")
def b37():
    return build_behaviours(load_annotations(participants=["P37"]))["P37"]


def test_scope_changes_a_count_as_the_annotations_do(p37, b37, lex):
    per: dict = {}
    for v in b37.videos:
        for s in b37.steps_by_video[v]:
            per.setdefault(s.action, {}).setdefault(v, 0)
            per[s.action][v] += 1
    a = max((a for a, c in per.items() if len(c) >= 2 and a.noun), key=lambda a: sum(per[a].values()))
    counts = {}
    for v in b37.videos:
        q = Query(operation="count", subject={"verb": a.verb, "objects": [a.noun]}, scope={"videos": [v]})
        counts[v] = recall(p37, "P37", q, lex).count or 0
    gold = {v: per[a].get(v, 0) for v in b37.videos}
    for v in b37.videos:
        assert abs(counts[v] - gold[v]) <= max(1, round(0.2 * gold[v])), (a, counts, gold)
    assert len(set(counts.values())) > 1 or len(set(gold.values())) == 1  # the answer moves with its scope


def test_last_thing_in_a_video_in_words(p37, b37, lex):
    video = b37.videos[-1]
    last = b37.steps_by_video[video][-1]
    a = answer_question(p37, "P37", f"And the last thing I did in {video} - what was it?", lex)
    assert a.log and a.log[0].video == video and abs(a.log[0].time_seconds - last.start_s) < 10, a.answer


def test_a_long_list_is_cut_and_says_how_to_see_the_rest(p37, b37, lex):
    video = max(b37.videos, key=lambda v: len(b37.steps_by_video[v]))
    a = answer_question(p37, "P37", f"What happened in {video}?", lex)
    assert a.cut and "between" in a.cut and str(len(a.log)) in a.cut
    early = answer_question(p37, "P37", f"What happened in {video} between 00:00 and 00:20?", lex)
    assert early.log and all(x.time_seconds <= 20 for x in early.log)


def test_misspelt_object_reads_as_the_person_s_word(p37, lex):
    right = answer_question(p37, "P37", "How many times did I take the chicken?", lex)
    slip = answer_question(p37, "P37", "How many times did I take the chiken?", lex)
    assert right.count and slip.count == right.count, (right.answer, slip.answer)


def test_a_word_the_person_never_says_widens_to_its_class_and_says_so(p37, lex):
    # "wok" is an instance of the pan class; P37's narrations never say wok
    said = answer_question(p37, "P37", "Have I ever used a pan?", lex)
    wok = answer_question(p37, "P37", "Have I ever used a wok?", lex)
    if said.yes:  # the class is in memory: the word is not, and the answer says it widened
        assert wok.yes is False and "no wok" in wok.answer and wok.widened
    else:
        assert not wok.yes


def test_explain_prints_the_query_and_empty_question_fails(small_bank):
    bank, _ = small_bank
    res = CliRunner().invoke(main, ["ask", str(bank), "How many times did I open the fridge in P37_101?",
                                    "--participant", "P37", "--explain"])
    assert res.exit_code == 0, res.output
    line = res.output.splitlines()[1]
    q = json.loads(line)
    assert q["operation"] == "count" and q["scope"] == {"videos": ["P37_101"]}
    res = CliRunner().invoke(main, ["ask", str(bank), "  ", "--participant", "P37"])
    assert res.exit_code != 0 and "empty question" in res.output


def test_scoped_generator_gold_and_the_counterfactual_check(small_bank):
    """Scoped kinds on P37: gold from the annotations, pairs that differ only in scope, and answers
    that change wherever the gold does."""
    from memora_graph.bench.generate_open import generate_open
    from memora_graph.bench.generate_scoped import SCOPED_KINDS
    from memora_graph.bench.open_eval import counterfactual, evaluate_open

    cohort = build_behaviours(load_annotations(participants=["P09", "P37"]))
    items = [i for i in generate_open(cohort["P37"], {"P09": cohort["P09"]}, seed=5) if i.kind in SCOPED_KINDS]
    b = cohort["P37"]
    for it in items:
        if it.kind == "count_video":  # the gold is the video's own count, not all memory's
            v, action = it.evidence["video"], tuple(it.evidence["action"])
            assert it.gold["count"] == sum(1 for s in b.steps_by_video[v] if tuple(s.action) == action)
    pairs = {}
    for it in items:
        if it.evidence.get("pair"):
            pairs.setdefault(it.evidence["pair"], []).append(it)
    assert any(len({str(i.gold) for i in group}) > 1 for group in pairs.values())
    records = evaluate_open(small_bank[0], {"P37": items})
    cf = counterfactual(records)
    assert cf["pairs"] >= 3 and cf["rate"] == 1.0, cf
    assert sum(r["correct"] for r in records) >= 0.8 * len(records)


def test_vocabulary_takes_remembered_steps_in_as_a_fresh_read_would(small_bank, lex):
    """A live view's vocabulary grows with the steps remembered since (only theirs are read), and
    equals the vocabulary of the whole log read at once."""
    from memora_graph.agent.query.log import step_log
    from memora_graph.agent.query.vocabulary import Vocabulary
    from memora_graph.retrieve.steps import StepRows

    with MemoryView.open(small_bank[0], "P37") as view:
        whole = Vocabulary.of(view, lex)
        words, names = dict(whole.words), {c: dict(n) for c, n in whole.names.items()}
        segs = view.fetch("_open_action_log")
        for key in ("_query_vocabulary", "_query_vocab_read"):  # start again from half the log ...
            view.__dict__.pop(key)
        half = step_log(StepRows.build(segs[: len(segs) // 2]), lex)
        grown = Vocabulary.of(view, lex, half)
        assert dict(grown.words) != words
        log = step_log(half.rows.added(segs[len(segs) // 2:]), lex, {}, half)  # ... as a live view remembers
        again = Vocabulary.of(view, lex, log)
        assert again is grown  # taken in, not read again
        assert dict(again.words) == words and {c: dict(n) for c, n in again.names.items()} == names




def test_a_class_is_named_in_the_persons_own_words(small_bank, lex):
    """Each class the narrations name is named by the person's most used word for it ("drying rack",
    "chopping board": a compound stays one name; the verb of "open drawer" is no part of it).
    Before, no name was ever recorded, so answers never used the person's words."""
    from memora_graph.agent.query.vocabulary import Vocabulary, _phrases

    def named(text):
        return [x for x in _phrases(lex, text.split()) if x[1]]

    assert named("put plate on drying rack") == [("plate", "plate"), ("drying rack", "rack:drying")]
    assert named("open drawer") == [("drawer", "drawer")]
    assert named("rinse chopping board") == [("chopping board", "board:chopping")]
    with MemoryView.open(small_bank[0], "P37") as view:
        vocab = Vocabulary.of(view, lex)
        assert len(vocab.names) >= 10
        for c in vocab.names:
            word = vocab.name(c)
            assert vocab.says(word) > 0, (c, word)  # a word the person said
            assert c in lex.noun_classes(word), (c, word)  # a word for that class


def test_every_operation_reads_a_grown_log_as_a_fresh_read(small_bank, lex):
    """The typed query reads the log as columns (query/steplog.py): the operations that scan it
    (relations, first / last / nth step, duration, scopes by video, window, moment and event)
    answer from a log grown by remembered segments (`StepRows.added`) as from the whole log read
    at once, and they answer (no operation falls over on the columns)."""
    from collections import Counter

    from memora_graph.agent.query.log import action_log
    from memora_graph.retrieve.steps import StepRows

    def answers(view) -> list[dict]:
        log = list(action_log(view, lex))
        acts = [k for k, _ in Counter((s.verb, s.objects[0]) for s in log if s.verb and s.objects).most_common(3)]
        video = sorted(view.videos)[0]
        out = []
        for (v, o), (v2, o2) in zip(acts, acts[1:] + acts[:1]):
            subj, anchor = {"verb": v, "objects": [o]}, {"verb": v2, "objects": [o2]}
            queries = [{"operation": op, "subject": subj} for op in ("where", "when", "count", "exists", "list",
                                                                     "steps", "duration")]
            queries += [{"operation": "list", "relation": rel, "anchor": anchor}
                        for rel in ("after", "before", "while", "instead_of")]
            queries += [{"operation": "list", "relation": "instead_of", "anchor": {"objects": [o2]}},
                        {"operation": "next", "subject": subj}, {"operation": "previous", "subject": subj},
                        {"operation": "list", "selector": "nth", "nth": 2, "subject": subj},
                        {"operation": "list", "selector": "last", "scope": {"videos": [video]}},
                        {"operation": "list", "scope": {"videos": [video], "at": 60}},
                        {"operation": "count", "subject": subj, "scope": {"videos": [video], "start": 10, "end": 200}},
                        {"operation": "count", "subject": subj, "scope": {"after": anchor}},
                        {"operation": "duration", "scope": {"session": 1}},
                        {"operation": "steps", "subject": {"objects": [o], "goal": f"make {o}"}}]
            for q in queries:
                a = recall(view, "P37", q, lex)
                assert a.kind and a.answer, q
                out.append(a.model_dump(mode="json"))
        return out

    with MemoryView.open(small_bank[0], "P37") as view:
        whole = answers(view)
    with MemoryView.open(small_bank[0], "P37") as view:
        segs = view.fetch("_open_action_log")
        view.__dict__["_steps"] = StepRows.build(segs[: len(segs) // 3]).added(segs[len(segs) // 3:])
        grown = answers(view)
    assert grown == whole and len(whole) > 40

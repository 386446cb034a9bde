"""Options read as claims about how a task is done, checked against task-pattern records."""

from __future__ import annotations

import pytest

from memora_graph.agent.claims import Claim, adjust, cues, verdict
from memora_graph.agent.reading import _reordered
from memora_graph.perceive.lexicon import Lexicon


@pytest.fixture(scope="module")
def lex():
    return Lexicon.load()


def _claim(family, way, verbs, nouns, share=1.0):
    return Claim(family, way, tuple(verbs), tuple(nouns), share, (f"P03:pref:{family}",))


def test_an_order_record_supports_its_order_and_contradicts_the_reverse(lex):
    c = _claim("order", "", ["empty", "wash"], ["saucepan"])
    assert verdict(c, "Empties it out before washing the saucepan.", cues("x"), lex) == 1.0
    assert verdict(c, "Washes the saucepan, then empties it.", cues("x"), lex) == -1.0
    assert verdict(c, "Washes the saucepan after emptying it.", cues("x"), lex) == 1.0  # "after" reverses
    assert verdict(c, "Dries the saucepan with a towel.", cues("x"), lex) == 0.0  # does not speak to it


def test_batch_repetition_and_staging_records(lex):
    one = _claim("batch", "one_at_a_time", ["take"], ["spoon"])
    a, b = "Retrieves one needed utensil from storage as the task requires.", "Lays out a broad utensil set before starting."
    assert verdict(one, a, cues(a), lex) == 1.0 and verdict(one, b, cues(b), lex) == -1.0
    rep = _claim("repetition", "alternate", ["stretch", "fold"], ["dough"])
    x, y = "Alternates stretching the dough and folding it back in repeated passes.", "Folds the dough once and leaves it."
    assert verdict(rep, x, cues(x), lex) == 1.0 and verdict(rep, y, cues(y), lex) < 0
    stage = _claim("staging", "", ["put", "take"], ["bottle"])
    z = "Uses the fridge as a short holding spot, then retrieves the bottle."
    assert verdict(stage, z, cues(z), lex) == 1.0
    assert verdict(stage, "Sets it aside to drain untouched.", cues("Sets it aside to drain untouched."), lex) == 0.0


def test_only_records_about_the_subject_speak_and_agreement_everywhere_is_silence(lex):
    opts = ["Retrieves one utensil as needed.", "Lays out a set of utensils first.", "Uses disposable tools.", "Keeps tools on the counter."]
    c = _claim("batch", "one_at_a_time", ["take"], ["spoon"], share=0.5)
    shifts, ids = adjust(opts, [c], {"knife"}, lex)
    assert shifts == [0.0] * 4
    shifts, ids = adjust(opts, [c], {"spoon"}, lex)
    assert shifts[0] > 0 > shifts[1] and shifts[2] == shifts[3] == 0.0 and ids[0] == ["P03:pref:batch"]


def test_records_reorder_the_options_but_keep_the_evidence_levels():
    scores, support = [2.0, 1.5, 1.0, 0.5], [["a"], ["b"], [], []]
    out, sup = _reordered(scores, support, [0.0, 0.8, 0.0, 0.0], [[], ["rec"], [], []])
    assert sorted(out, reverse=True) == sorted(scores, reverse=True)
    assert out[1] == 2.0 and out[0] == 1.5 and sup[1] == ["rec", "b"]
    assert _reordered(scores, support, [0.0] * 4, [[]] * 4) == (scores, support)


def test_the_reader_reranks_with_claims_unless_turned_off(monkeypatch, lex):
    """The claims re-rank the offline reader's options by default; MEMORA_TASK_CLAIMS=off reads
    the task records as any other record (the reader of before them)."""
    from memora_graph.agent import reading

    calls = []
    real = reading.task_claims

    def spy(*args):
        calls.append(args)
        return real(*args)

    monkeypatch.setattr(reading, "task_claims", spy)
    claim = _claim("order", "before", ("empty", "wash"), ("pan:sauce",))
    events = [reading.Event("P03_101", 12.0 + k, verb, ("pan:sauce",), (f"P03_101#{k}",), 1.0, "log",
                            text=f"{verb} saucepan") for k, verb in enumerate(["empty", "wash", "rinse", "dry"])]
    events.append(reading.Event("", -1.0, "empty", ("pan:sauce",), ("P03:pref:order",), 1.0, "pattern",
                                text="empties the saucepan before washing it", claim=claim))
    question = "What is P03's approach to handling the saucepan during cleanup?"
    choices = ["Empties it out before washing the saucepan.", "Washes the saucepan before emptying it.",
               "Leaves the saucepan to soak overnight.", "Puts the saucepan straight in the cupboard."]
    monkeypatch.setenv("MEMORA_TASK_CLAIMS", "off")
    reading.score(question, choices, events, lex)
    assert not calls
    monkeypatch.delenv("MEMORA_TASK_CLAIMS", raising=False)
    reading.score(question, choices, events, lex)
    assert calls


def test_a_portion_at_a_time_is_one_at_a_time_and_repeated_passes(lex):
    """"Adds some, then returns for more" claims what a one-at-a-time batch record and a
    repetition record hold, and contradicts a record that the person lays out a set first."""
    opts = {"Adds some cereal, then returns to the bag for more.": ["cereal", "bag"],
            "Scrubs one fork, then reaches for another to continue the sequence.": ["fork"],
            "Adds meat in portions, returning to the pan between additions.": ["meat", "pan"],
            "Works slice by slice, breaking each piece into the bowl before taking another.": ["bowl"]}
    for o, nouns in opts.items():
        one = _claim("batch", "one_at_a_time", ["take"], nouns)
        lot = _claim("batch", "batch", ["take"], nouns)
        rep = _claim("repetition", "repeat", ["pour"], nouns)
        cue = cues(o)
        assert "more" in cue, o
        assert verdict(one, o, cue, lex) == 1.0 and verdict(lot, o, cue, lex) == -1.0 and verdict(rep, o, cue, lex) > 0
    rep = _claim("repetition", "repeat", ["pour"], ["cereal"])
    single = "Pours one measured serving from the bag and stops there."
    assert "more" not in cues(single) and verdict(rep, single, cues(single), lex) == 0.0
    assert "batch" in cues("Sets forks aside to soak before washing them all later.")


def test_claims_are_about_the_objects_handled_not_the_places_named(lex):
    from memora_graph.agent.reading import claim_subject, parse_question

    intent = parse_question("What approach does P02 take when gathering cherry tomatoes from the box?", lex)
    assert "box" in intent.subject_nouns and claim_subject(intent) == {"tomato"}
    bare = parse_question("What is P02's approach to portioning cereal into the bowl?", lex)
    assert claim_subject(bare) == set(bare.subject_nouns)  # no clause names an object: every subject noun


def test_whether_to_answer_is_read_before_the_records_rerank(monkeypatch, lex):
    """The records move an option up; whether memory supports any answer at all (the calibration's
    features, hence abstaining) is read from the evidence as it stood before they did."""
    from memora_graph.agent import reading

    events = [reading.Event("P03_101", 12.0 + k, verb, ("pan:sauce",), (f"P03_101#{k}",), 1.0, "log",
                            text=f"{verb} saucepan") for k, verb in enumerate(["empty", "wash", "rinse", "dry"])]
    events.append(reading.Event("P03_102", 40.0, "put", ("pan:sauce", "cupboard"), ("P03_102#0",), 1.0, "log",
                                text="put saucepan in cupboard"))
    question = "What is P03's approach to handling the saucepan during cleanup?"
    choices = ["Empties it out before washing the saucepan.", "Washes the saucepan and wipes the counter.",
               "Leaves the saucepan to soak overnight.", "Puts the saucepan away in the cupboard."]
    monkeypatch.setenv("MEMORA_TASK_CLAIMS", "off")
    off = reading.score(question, choices, events, lex)
    monkeypatch.delenv("MEMORA_TASK_CLAIMS", raising=False)
    best = max(range(4), key=lambda i: (off.scores[i], -i))
    worst = min(range(4), key=lambda i: (off.scores[i], -i))
    monkeypatch.setattr(reading, "task_claims",
                        lambda choices, *a: ([100.0 if i == worst else 0.0 for i in range(4)], [[] for _ in range(4)]))
    on = reading.score(question, choices, events, lex)
    assert len(set(off.scores)) == 4 and worst != best
    assert max(range(4), key=lambda i: (on.scores[i], -i)) == worst
    assert on.features == off.features


def test_a_staging_record_speaks_only_for_the_usual_way(lex):
    z = "Uses the fridge as a short holding spot, then retrieves the bottle."
    assert verdict(_claim("staging", "", ["put", "take"], ["bottle"], share=0.8), z, cues(z), lex) == 1.0
    # staged in 3 of 22 tasks: the person does not usually stage it, so it supports no staging claim
    assert verdict(_claim("staging", "", ["put", "take"], ["bottle"], share=3 / 22), z, cues(z), lex) == 0.0


def test_a_batch_record_speaks_only_to_taking_putting_or_moving(lex):
    """How the person fetches and carries potatoes says nothing about how they stir them."""
    lot = _claim("batch", "batch", ["take"], ["potato"])
    stir = "Separates all of the potato pieces first, then stirs them afterward."
    carry = "Gathers all the potatoes together, then puts them on the board."
    assert "batch" in cues(stir) and verdict(lot, stir, cues(stir), lex) == 0.0
    assert verdict(lot, carry, cues(carry), lex) == 1.0


def test_a_record_speaks_only_to_options_about_its_objects(lex):
    """A batch record about taking bowls one at a time says nothing of how cereal is portioned; one
    about how the food is fetched says nothing of the waste; an option that names no particular
    object ("sets it aside", "a utensil") is about the question's subject."""
    bowls = _claim("batch", "one_at_a_time", ["take"], ["bowl"])
    cereal = "Adds some cereal, then returns to the bag for more."
    assert verdict(bowls, cereal, cues(cereal), lex) == 0.0
    food = _claim("batch", "batch", ["take"], ["food"])
    waste = "Collects all waste on the counter and clears it only after every food item is finished."
    assert verdict(food, waste, cues(waste), lex) == 0.0
    assert verdict(food, "Gathers it all together, then puts it down.", cues("Gathers it all together"), lex) == 1.0
    spoons = _claim("batch", "one_at_a_time", ["take"], ["spoon"])
    one = "Retrieves one needed utensil from storage as the task requires."
    assert verdict(spoons, one, cues(one), lex) == 1.0


def test_order_setup_and_carrier_records_speak_of_their_own_actions(lex):
    """An order record holds for its two actions, not for any of their kind; a setup record's
    taking and putting down frame every task and set nothing up; a carrier record speaks to the
    same transfer, not to any option that names its tool."""
    order = _claim("order", "", ["squeeze", "wash"], ["sponge"])
    rinse = "Rinses the sponge under the tap before using it for washing."
    assert verdict(order, rinse, cues(rinse), lex) == 0.0
    assert verdict(order, "Squeezes the sponge, then washes it.", cues("x"), lex) == 1.0
    setup = _claim("setup", "mix meat", ["hold", "put", "take"], ["pan", "lid"])
    aside = "Sets the pan aside to soak before adding detergent."
    assert verdict(setup, aside, cues(aside), lex) == 0.0
    opens = _claim("setup", "store food", ["open", "take"], ["container"])
    first = "Opens the containers first, then puts the food into them."
    assert verdict(opens, first, cues(first), lex) == 1.0
    jar = _claim("carrier", "with", ["pour"], ["spice", "jar"])
    assert verdict(jar, "Leaves the jar open.", cues("Leaves the jar open."), lex) == 0.0
    assert verdict(jar, "Pours the spice from the jar.", cues("x"), lex) == 1.0


def test_a_closure_record_speaks_to_options_naming_its_object_whatever_the_question_calls_it(lex):
    """'When P01 finishes accessing upper storage, what closure pattern...': the question names no
    cupboard, the options do. The person's record about the cupboard supports closing it and
    contradicts leaving it open; one about the drawer says nothing of the cupboard."""
    opts = ["Blocks it with cookware", "Leaves cupboard open", "Reopens it repeatedly", "Closes cupboard after use"]
    closes = _claim("closure", "closes", ["open", "close"], ["cupboard"], share=0.85)
    shifts, ids = adjust(opts, [closes], set(), lex)
    assert shifts[3] > 0 > shifts[1] and shifts[0] == shifts[2] == 0.0
    assert ids[3] == ["P03:pref:closure"]
    drawer = _claim("closure", "closes", ["open", "close"], ["drawer"], share=1.0)
    assert adjust(opts, [drawer], set(), lex)[0] == [0.0] * 4
    # a person who leaves the bag open: the record says the opposite of the usual wording
    bag = _claim("closure", "leaves_open", ["open", "close"], ["bag"], share=6 / 7)
    a, b = "Leaves the bag open until the end of the task.", "Folds the bag and closes it straight after."
    assert verdict(bag, a, cues(a), lex) == 1.0 and verdict(bag, b, cues(b), lex) == -1.0
    both = "Leaves the inner bag open but closes the cupboard door."
    assert verdict(bag, both, cues(both), lex) == 0.0  # says both: no verdict

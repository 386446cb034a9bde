"""`memora plan --from-task` over a real bank: the person's task that does the goal, its key objects
in their remembered order, no place carried, no cycle repeated; and the place guard of every plan."""

from __future__ import annotations

import csv

import pytest

from memora_graph.agent import task_match
from memora_graph.agent.planner import plan
from memora_graph.agent.task_plan import acts_on_place, without_places
from memora_graph.perceive.lexicon import Lexicon

TEA = ["open cupboard", "take cup", "close cupboard", "put cup on counter", "take kettle", "turn on tap",
       "fill kettle", "turn off tap", "turn on kettle", "open cupboard", "take teabag", "close cupboard",
       "put teabag in cup", "take kettle", "pour water into cup", "put kettle on counter", "open fridge",
       "take milk", "pour milk into cup", "put milk in fridge", "close fridge"]
KNIVES = ["turn on tap", "take sponge"] + ["take knife", "scrub knife", "rinse knife", "put knife on drying rack"] * 3 + \
    ["turn off tap", "put sponge on sink"]
TIDY = ["open fridge", "take butter", "put butter in fridge", "take cheese", "put cheese in fridge", "close fridge"]


@pytest.fixture(scope="module")
def tea_bank(tmp_path_factory):
    from memora_graph.pipeline import build_bank

    root = tmp_path_factory.mktemp("teabank")
    path = root / "narrations.csv"
    rows = []
    for video, texts in (("P01_01", TEA + KNIVES), ("P01_02", TEA + TIDY)):
        for i, text in enumerate(texts):
            rows.append({"video_id": video, "start": 2.0 * i, "end": 2.0 * i + 1.5, "text": text})
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["video_id", "start", "end", "text"])
        w.writeheader()
        w.writerows(rows)
    bank = root / "bank"
    build_bank(bank, None, narrations=path, participant="P01")
    return bank


def _objects(result) -> list[str]:
    return [str(s["object"]) for s in result.steps]


def test_a_tea_plan_keeps_cup_kettle_and_teabag_in_their_order_and_carries_no_place(tea_bank):
    lex = Lexicon.load()
    result = plan(tea_bank, "P01", "make a cup of tea", from_task=True)
    objects = _objects(result)
    assert any(s.get("source") == "task" for s in result.steps)  # from the person's task, not composed
    first = {o: objects.index(o) for o in ("cup", "kettle", "tea") if o in objects}  # "teabag" is read as tea
    assert set(first) == {"cup", "kettle", "tea"}
    assert first["cup"] < first["kettle"] < first["tea"]  # the order the person did it in
    assert not any(acts_on_place(s["verb_class"], s["object"], lex) for s in result.steps if s.get("verb_class"))
    said = [(s["verb"], s["object"], s["place"]) for s in result.steps]
    assert len(said) == len(set(said))  # nothing said twice
    assert all("not in memory" not in s["text"] for s in result.steps)  # the task's objects are the person's


def test_a_washing_cycle_done_three_times_is_planned_once(tea_bank):
    result = plan(tea_bank, "P01", "wash the knife", from_task=True)
    texts = [s["text"].lower() for s in result.steps]
    assert sum("scrub the knife" in t for t in texts) == 1
    assert any("knife" in t and "drying rack" in t for t in texts)
    assert all("tea" not in t and "milk" not in t for t in texts)  # only the knife's steps of that task


def test_tasks_are_read_and_a_goal_no_task_does_is_composed(tea_bank):
    from memora_graph.retrieve.registry import get_family

    lex = Lexicon.load()
    view = get_family("memora").open(tea_bank, "P01")
    try:
        tasks = task_match.read_tasks(view)
        assert task_match.read_tasks(view) is tasks  # the view keeps them for its next plans
        assert {t["goal"] for t in tasks} >= {"make tea"}
        assert task_match.best("make a cup of tea", tasks, lex)[0]["goal"] == "make tea"
        assert task_match.best("fry the egg", tasks, lex) is None  # no task does it: plan as usual
        assert task_match.best("make a cup of tea", list(tasks), lex)[0]["id"] == \
            task_match.best("make a cup of tea", tasks, lex)[0]["id"]  # rows read whole match as the index does
    finally:
        view.close()
    composed = plan(tea_bank, "P01", "fry the egg", from_task=True)
    assert not any(s.get("source") == "task" for s in composed.steps)


def test_no_step_of_any_draft_carries_a_place():
    lex = Lexicon.load()
    draft = [{"verb_class": "put", "noun": "fridge", "name": "fridge", "place": "fridge area"},
             {"verb_class": "take", "noun": "hob", "name": "pot hob", "place": "hob"},
             {"verb_class": "open", "noun": "fridge", "name": "fridge", "place": ""},
             {"verb_class": "take", "noun": "cup", "name": "cup", "place": "cupboard"}]
    kept = without_places(draft, lex)
    assert [(d["verb_class"], d["noun"]) for d in kept] == [("take", "pot"), ("open", "fridge"), ("take", "cup")]


def test_how_one_usually_does_a_task_is_answered_with_its_stages(tea_bank):
    from memora_graph.agent.ask import ask

    result = ask(tea_bank, "P01", "how do I usually make tea?")
    assert "task 'make tea'" in result.answer and "main:" in result.answer
    assert "kettle" in result.answer


def test_memora_plan_starts_from_the_persons_task_unless_told_to_compose(tea_bank):
    """A person's own goal is planned from their task that does it by default (`memora plan`, the
    server's plan tool); --compose gives the composed plan the benchmark's offline policy makes."""
    from click.testing import CliRunner

    from memora_graph.cli import main

    run = CliRunner().invoke
    default = run(main, ["plan", str(tea_bank), "make a cup of tea", "--participant", "P01", "--json"])
    composed = run(main, ["plan", str(tea_bank), "make a cup of tea", "--participant", "P01", "--json", "--compose"])
    assert default.exit_code == 0 and composed.exit_code == 0, default.output + composed.output
    import json

    steps, csteps = json.loads(default.output)["steps"], json.loads(composed.output)["steps"]
    assert any(s.get("source") == "task" for s in steps)
    assert not any(s.get("source") == "task" for s in csteps)
    assert [s["text"] for s in steps] == [s["text"] for s in plan(tea_bank, "P01", "make a cup of tea").steps]


def test_a_plan_reads_every_task_however_many_come_before_the_one_that_does_the_goal(tea_bank, tmp_path):
    """A person has tens of thousands of tasks at 1,000 h (39,787); the servers' `tasks` query stops at
    1,000 rows. A plan reads every task (retrieve/tasks.py): 1,100 knife wash-ups recorded in an
    earlier video than the tea do not hide it."""
    import shutil

    from memora_graph import schema
    from memora_graph.bank import Bank
    from memora_graph.retrieve.registry import get_family

    bank = tmp_path / "bank"
    shutil.copytree(tea_bank, bank)
    b = Bank(bank)
    store = b.open("P01", read_only=False)
    try:
        rows = store.fetch("_tasks_all", participant="P01")
        knife = next(r for r in rows if r["goal"] == "wash up knife")
        filler = [{**knife, "id": f"P01:task:filler{n:04d}", "participant": "P01", "video": "P01_00", "t_start": float(n)}
                  for n in range(1100)]
        store.copy("Task", schema.frame("Task", filler))
    finally:
        store.close()
    b.record_integrity("P01")
    view = get_family("memora").open(bank, "P01")
    try:
        tasks = task_match.read_tasks(view)
        assert len(tasks) == len(rows) + 1100
        assert [t["id"] for t in tasks] == [r["id"] for r in view.fetch("_tasks_all")]  # in video and time order
        assert len(view.fetch("tasks")) == 1000  # what a plan read before
    finally:
        view.close()
    result = plan(bank, "P01", "make a cup of tea")
    started = [s for s in result.steps if s.get("source") == "task"]
    assert started and not any(e.startswith("P01:task:filler") for s in started for e in s["evidence"])
    assert {"cup", "kettle"} <= {str(s["object"]) for s in started}


def test_a_view_reads_its_tasks_again_after_a_consolidation_and_bad_steps_name_the_task(tea_bank):
    import polars as pl

    from memora_graph.errors import BankError
    from memora_graph.retrieve.registry import get_family
    from memora_graph.retrieve.tasks import TaskIndex

    view = get_family("memora").open(tea_bank, "P01")
    try:
        kept = task_match.read_tasks(view)
        view.reload_inferred()  # what live memory does after its incremental consolidation
        again = task_match.read_tasks(view)
        assert again is not kept and [t["id"] for t in again] == [t["id"] for t in kept]
    finally:
        view.close()
    rows = pl.DataFrame({"id": ["P01:task:good", "P01:task:bad"], "goal": ["make tea", "wash up"],
                         "family": ["cooking", "cleanup"], "objects": [["cup"], ["knife"]],
                         "steps": ['[{"verb": "take", "noun": "cup"}]', '[{"verb": "take", "noun": ']})
    with pytest.raises(BankError, match="P01:task:bad"):
        TaskIndex(rows, source="banks/p01/P01.kuzu")


def test_a_plan_never_puts_down_what_it_has_not_taken():
    """A thing put down and taken straight back up (P30's toast: "put down pitta bread", "take pitta
    bread") was in hand before the kept steps: the plan takes it, and does not start by putting it
    down. A thing taken and put straight back is moved aside: neither is planned."""
    lex = Lexicon.load()

    def step(verb, noun, place="counter area"):
        return {"verb": verb, "noun": noun, "place": place, "instrument": ""}

    task = {"id": "P30:task:t", "goal": "make toast", "main_object": "toaster", "segments": [],
            "steps": [step("put", "pitta_bread"), step("take", "pitta_bread"), step("close", "cupboard"),
                      step("insert", "pitta_bread", "toaster"), step("take", "knife"), step("put", "knife"),
                      step("turn-on", "toaster")]}
    kept = [(s["verb"], s["noun"]) for s in task_match.focus(task, {"pitta_bread", "toaster", "knife"}, lex)]
    assert kept == [("take", "pitta_bread"), ("close", "cupboard"), ("insert", "pitta_bread"), ("turn-on", "toaster")]


def test_a_long_task_is_planned_whole_not_cut_at_the_composed_plans_length():
    """P30's coffee is 37 focused steps (the water boiled, the filter folded, the beans ground, the
    water poured last): a plan from it keeps them all, the last ones too, not the first 20."""
    from memora_graph.agent.planner import MAX_PLAN_STEPS, compose_structured

    lex = Lexicon.load()
    places = ["cup", "jug", "filter", "can", "kettle", "bowl", "glass", "mug"]
    verbs = ["pour", "insert", "empty", "scoop"]
    steps = [{"verb": v, "noun": "coffee", "place": p, "instrument": "", "segment": f"P30_103#t{i:04d}"}
             for i, (v, p) in enumerate((v, p) for p in places for v in verbs)]
    steps.append({"verb": "turn-on", "noun": "coffee_maker", "place": "counter area", "instrument": "",
                  "segment": "P30_103#t0099"})
    task = {"id": "P30:task:c", "video": "P30_103", "goal": "make coffee", "family": "cooking",
            "main_object": "coffee", "segments": ["P30_103#t0000"], "steps": steps}
    out = compose_structured("make coffee", [], lex, from_task=True, tasks=[task])
    assert len(steps) > MAX_PLAN_STEPS and len(out) == len(steps)
    assert out[-1]["verb"].startswith("turn") and "coffee maker" in out[-1]["text"]

"""Task-level memory: videos cut into tasks, named by goal, with stages; one detector per pattern
family on hand-built tasks; the tasks written to and read from a real bank, ids stable."""

from __future__ import annotations

import json
import shutil

from memora_graph.bank import Bank
from memora_graph.consolidate import finish_participant, load_memory
from memora_graph.consolidate.memory import MemoryStep, Obj, ParticipantMemory
from memora_graph.consolidate.patterns import batch, canonical, carrier, closure, detect_all, order, repetition, setup, staging
from memora_graph.consolidate.records import StepAction
from memora_graph.consolidate import task_rows as task_rows_module
from memora_graph.consolidate.task_rows import TaskRows
from memora_graph.consolidate.task_records import CompactTask, Task
from memora_graph.consolidate.tasks import PAUSE, cut, segment_tasks, video_tasks
from memora_graph.store import Store

SAUCEPAN = ("saucepan", "cookware", False)
SPONGE = ("sponge", "cleaning equipment and material", False)
TAP = ("tap", "fixture", True)
DOUGH = ("dough", "baked goods and grains", False)
SPOON = ("spoon", "cutlery", False)
KNIFE = ("knife", "cutlery", False)
ONION = ("onion", "vegetables", False)
LEAF = ("leaf", "vegetables", False)
BIN = ("bin", "fixture", True)


def _step(video, t, verb, *objects, dest="", loc="sink_area", zone=""):
    objs = [Obj(kind, f"P01:{kind}", cat, fixture) for kind, cat, fixture in objects]
    return MemoryStep(video=video, segment=f"{video}#t{int(t // 10):04d}", t=t, verb=verb, objects=objs, location=loc,
                      zone=zone, destination=dest, relation="INSIDE" if dest else "", narration=f"{verb} {objects[0][0]}")


def _washing_up(video, t0):
    """Empty the saucepan, then wash it with the sponge and rinse it: a cleanup task at the sink."""
    return [_step(video, t0, "take", SAUCEPAN), _step(video, t0 + 2, "empty", SAUCEPAN, dest="sink"),
            _step(video, t0 + 4, "turn-on", TAP), _step(video, t0 + 5, "take", SPONGE),
            _step(video, t0 + 7, "wash", SAUCEPAN, SPONGE), _step(video, t0 + 9, "rinse", SAUCEPAN),
            _step(video, t0 + 11, "turn-off", TAP), _step(video, t0 + 12, "put", SAUCEPAN, dest="drying_rack")]


def _dough(video, t0):
    """Stretch, fold, stretch, fold the dough on the counter."""
    verbs = ["take", "stretch", "fold", "stretch", "fold", "stretch", "fold", "put"]
    return [_step(video, t0 + 2 * i, v, DOUGH, loc="counter_area") for i, v in enumerate(verbs)]


def test_a_pause_or_a_move_to_new_objects_starts_a_new_task():
    steps = _washing_up("P01_101", 0.0) + _dough("P01_101", 20.0)  # moved to the counter, other objects
    pieces = cut(steps)
    assert [len(p) for p in pieces] == [8, 8]
    later = _washing_up("P01_101", 0.0) + [_step("P01_101", 12 + PAUSE + 1, "wash", SAUCEPAN),
                                           *(_step("P01_101", 12 + PAUSE + 2 + i, "rinse", SAUCEPAN) for i in range(3))]
    assert len(cut(later)) == 2  # same objects, but after a pause
    same = _washing_up("P01_101", 0.0) + [_step("P01_101", 14 + i, "rinse", SAUCEPAN, loc="counter_area") for i in range(4)]
    assert len(cut(same)) == 1  # moved, but the objects continue


def test_a_change_of_work_at_one_place_starts_a_new_task_with_the_steps_that_fetch_for_it():
    # no pause, no move: cut the onion, then wash up at the same counter
    v = "P01_101"
    cutting = [_step(v, i, "cut", ONION, KNIFE, loc="counter_area") for i in range(5)]
    fetch = [_step(v, 5, "turn-on", TAP, loc="counter_area"), _step(v, 6, "take", SAUCEPAN, loc="counter_area")]
    washing = [_step(v, 7 + i, verb, SAUCEPAN, SPONGE, loc="counter_area")
               for i, verb in enumerate(["wash", "scrub", "rinse", "wash", "rinse"])]
    pieces = cut(cutting + fetch + washing)
    assert [len(p) for p in pieces] == [5, 7]  # the tap and taking the saucepan open the wash-up
    assert [t.goal for t in video_tasks("P01", cutting + fetch + washing)] == ["prepare onion", "wash up saucepan"]
    one_off = cutting + [_step(v, 5, "wash", KNIFE, loc="counter_area")] + cutting[:3]
    assert len(cut(one_off)) == 1  # one rinse of the knife between cuts is no new task


def test_a_task_is_named_after_its_product_unless_it_washes_or_stores_it():
    v = "P01_101"
    tea, kettle, cup = ("tea", "drinks", False), ("kettle", "appliances", False), ("cup", "crockery", False)
    making = [_step(v, 0, "fill", kettle), _step(v, 1, "turn-on", kettle), _step(v, 2, "take", tea),
              _step(v, 3, "insert", tea, dest="cup"), _step(v, 4, "pour", ("water", "drinks", False), dest="cup")]
    assert video_tasks("P01", making)[0].goal == "make tea"
    assert video_tasks("P01", making[:2] + [_step(v, 3, "pour", ("water", "drinks", False))])[0].goal == "boil water"
    washing = [_step(v, i, verb, cup, SPONGE) for i, verb in enumerate(["wash", "scrub", "rinse"])] + \
        [_step(v, 4, "take", tea), _step(v, 5, "put", tea)]
    assert video_tasks("P01", washing)[0].goal == "wash up cup"  # the tea handled there is not made


def _coffee(v, t0, loc):
    """Spoon coffee into the coffee maker and switch it on (at `loc`)."""
    coffee, maker = ("coffee", "drinks", False), ("coffee_maker", "appliances", False)
    return [_step(v, t0, "take", maker, loc=loc), _step(v, t0 + 1, "take", SPOON, loc=loc),
            _step(v, t0 + 2, "scoop", coffee, SPOON, dest="coffee_maker", loc=loc),
            _step(v, t0 + 3, "turn-on", maker, loc=loc)]


def test_consecutive_pieces_of_one_goal_are_one_task_unless_a_pause_parts_them():
    v = "P01_101"
    paper = ("filter", "cleaning equipment and material", False)
    # coffee, then a filter fetched and folded at the cupboard (a move to objects the coffee steps do
    # not share cuts there), then coffee again: one making of coffee
    fetch = [_step(v, 5 + i, verb, paper, loc="cabinet_area") for i, verb in enumerate(["take", "fold", "open", "put"])]
    steps = _coffee(v, 0.0, "counter_area") + fetch + _coffee(v, 9.0, "cabinet_area")
    assert [len(p) for p in cut(steps)] == [4, 8]  # cut at the move to the filter, each piece making coffee
    tasks = video_tasks("P01", steps)
    assert [t.goal for t in tasks] == ["make coffee"]
    assert len(tasks[0].steps) == len(steps) and tasks[0].t_start == 0.0 and tasks[0].t_end == 12.0
    assert tasks[0].places == ["counter_area", "cabinet_area"]
    later = _coffee(v, 0.0, "counter_area") + [_step(v, s.t + PAUSE, s.verb, *[(o.kind, o.category, o.is_fixture)
                                                                              for o in s.objects], dest=s.destination,
                                                     loc=s.location) for s in fetch + _coffee(v, 9.0, "cabinet_area")]
    assert [t.goal for t in video_tasks("P01", later)] == ["make coffee", "make coffee"]  # a pause parts them


def test_putting_several_foods_away_is_putting_away_groceries():
    v = "P01_101"
    fridge = ("fridge", "fixture", True)
    foods = [("milk", "dairy and eggs"), ("butter", "dairy and eggs"), ("carrot", "vegetables")]
    steps = [_step(v, 0, "open", fridge, loc="fridge_area")]
    for i, (kind, cat) in enumerate(foods):
        steps += [_step(v, 1 + 2 * i, "take", (kind, cat, False), loc="fridge_area"),
                  _step(v, 2 + 2 * i, "insert", (kind, cat, False), dest="fridge", loc="fridge_area")]
    assert video_tasks("P01", steps)[0].goal == "put away groceries"
    assert video_tasks("P01", steps[:5])[0].goal == "put away milk"  # two foods: no shopping


def test_tasks_are_named_by_goal_with_stages_tools_places_and_stable_ids():
    steps = _washing_up("P01_101", 0.0) + _dough("P01_101", 20.0)
    wash, dough = video_tasks("P01", steps)
    assert wash.goal == "wash up saucepan" and wash.family == "cleanup"
    assert dough.goal == "stretch dough" and dough.main_object == "dough"  # its cooking verb, not a plain "cook"
    assert [s.stage for s in wash.steps][:2] == ["setup", "setup"]  # take, empty: before the first wash... verb
    assert "main" in {s.stage for s in wash.steps}
    assert wash.tools == ["sponge"] and wash.places == ["sink_area"]
    assert wash.segments[0] == "P01_101#t0000"
    again = video_tasks("P01", list(reversed(steps)))  # same steps, any order in: same tasks, same ids
    assert [t.id for t in again] == [wash.id, dough.id]


def _tasks():
    steps = []
    for i, v in enumerate(["P01_101", "P01_102", "P01_103"]):
        steps += _washing_up(v, 0.0) + _dough(v, 20.0)
    return segment_tasks(ParticipantMemory("P01", segments=[{"id": s.segment, "video": s.video} for s in steps], steps=steps))


def test_order_invariant_counts_n_of_m_and_names_the_exceptions():
    tasks = _tasks()
    # a fourth video washes before emptying: the exception
    odd = video_tasks("P01", [_step("P01_104", 0, "wash", SAUCEPAN), _step("P01_104", 2, "empty", SAUCEPAN, dest="sink"),
                              _step("P01_104", 4, "rinse", SAUCEPAN), _step("P01_104", 6, "put", SAUCEPAN)])
    found = {p.key: p for p in order.detect(tasks + odd)}
    p = found[("saucepan", "empty", "wash")]
    assert (p.count, p.total) == (3, 4) and p.exceptions == ["P01_104#t0000"]
    assert p.statement.startswith("Empties the saucepan before washing it (3 of 4")
    assert ("saucepan", "take", "wash") not in found  # taking frames every action: not an invariant
    assert ("dough", "stretch", "fold") not in found  # interleaved: a repetition, not an order


def test_alternation_is_found_and_a_single_pass_is_not():
    found = {p.key: p for p in repetition.detect(_tasks())}
    alt = found[("alternate", "dough", "stretch", "fold")]
    assert alt.count == 3 and alt.detail["cycles"] == 9
    assert "Alternates stretching and folding the dough" in alt.statement
    assert not any(k[0] == "alternate" and k[1] == "saucepan" for k in found)


def test_one_at_a_time_against_a_batch():
    def leaves(video, gathered):
        if gathered:
            verbs = [("take", LEAF, ""), ("take", LEAF, ""), ("take", LEAF, ""), ("insert", LEAF, "bin")]
        else:
            verbs = [("take", LEAF, ""), ("insert", LEAF, "bin"), ("take", LEAF, ""), ("insert", LEAF, "bin")]
        return [_step(video, 2 * i, v, o, dest=d, loc="counter_area") for i, (v, o, d) in enumerate(verbs)]
    one = [t for v in ("P01_101", "P01_102") for t in video_tasks("P01", leaves(v, False))]
    found = {p.key: p for p in batch.detect(one)}
    assert found[("carry", "leaf", "one")].statement.startswith("Handles the leaf one at a time")
    many = [t for v in ("P01_101", "P01_102", "P01_103") for t in video_tasks("P01", leaves(v, True))]
    found = {p.key: p for p in batch.detect(one + many)}
    assert found[("carry", "leaf", "batch")].count == 3 and found[("carry", "leaf", "batch")].total == 5


def test_two_takes_in_a_row_put_down_one_by_one_are_no_batch():
    """Taking an object twice in a row and putting it down once (a re-grasp, or a portion at a
    time) says neither way; two taken, then two put down together, is a batch."""
    def meat(video, verbs):
        return [_step(video, 2 * i, v, LEAF, dest=d, loc="counter_area") for i, (v, d) in enumerate(verbs)]
    regrasp = [("take", ""), ("take", ""), ("put", "pan"), ("take", ""), ("put", "pan")]
    together = [("take", ""), ("take", ""), ("put", "pan"), ("put", "pan")]
    tasks = [t for v in ("P01_101", "P01_102", "P01_103") for t in video_tasks("P01", meat(v, regrasp))]
    assert not [p for p in batch.detect(tasks) if p.key[0] == "carry"]
    tasks += [t for v in ("P01_104", "P01_105") for t in video_tasks("P01", meat(v, together))]
    found = {p.key: p for p in batch.detect(tasks)}
    assert found[("carry", "leaf", "batch")].count == 2 and found[("carry", "leaf", "batch")].total == 2


def test_staging_setup_carrier_and_canonical_stages():
    tasks = []
    for v in ("P01_101", "P01_102"):
        steps = [_step(v, 0, "open", ("drawer", "fixture", True), loc="cabinet_area"),
                 _step(v, 1, "take", KNIFE, loc="cabinet_area", zone="drawer"),
                 _step(v, 3, "put", KNIFE, dest="board", loc="counter_area"),
                 _step(v, 4, "take", ONION, loc="counter_area"), _step(v, 5, "cut", ONION, KNIFE, loc="counter_area"),
                 _step(v, 7, "take", KNIFE, loc="counter_area"), _step(v, 8, "cut", ONION, KNIFE, loc="counter_area"),
                 _step(v, 9, "scoop", ONION, SPOON, dest="pan", loc="counter_area")]
        tasks += video_tasks("P01", steps)
    assert {t.goal for t in tasks} == {"prepare onion"}
    st = {p.key for p in staging.detect(tasks)}
    assert ("knife", "board") in st
    su = {p.key: p for p in setup.detect(tasks)}
    assert su[("goal", "prepare onion")].count == 2
    assert ("object", "open", "drawer") in su
    ca = {p.key: p for p in carrier.detect(tasks)}
    assert ca[("onion", "pan", "spoon")].statement.startswith("Transfers the onion into the pan with the spoon")
    can = canonical.detect(tasks)[0]
    assert can.detail["stages"]["main"][0] == "cut onion" and can.count == 2


def test_a_step_done_in_different_stages_across_occurrences_is_still_canonical():
    """Folding the filter is setup one morning (before the coffee) and main the next (between
    spoonfuls): done most times, it is a canonical step, in the stage it is in most."""
    paper = ("filter", "cleaning equipment and material", False)
    coffee = ("coffee", "drinks", False)
    tasks = []
    for n, v in enumerate(("P01_101", "P01_102", "P01_103", "P01_104", "P01_105")):
        fold = [_step(v, 0, "take", paper), _step(v, 1, "fold", paper)]
        spoon = [_step(v, 2, "take", SPOON), _step(v, 3, "scoop", coffee, SPOON, dest="coffee_maker"),
                 _step(v, 4, "scoop", coffee, SPOON, dest="coffee_maker")]
        # folded first twice, between spoonfuls twice, not at all once: in 4 of 5, in no stage in half
        steps = fold + spoon if n < 2 else spoon[:2] + fold + spoon[2:] if n < 4 else spoon + [_step(v, 5, "take", paper)]
        steps = [_step(v, i, s.verb, *[(o.kind, o.category, o.is_fixture) for o in s.objects], dest=s.destination)
                 for i, s in enumerate(steps)]  # times in the order given
        tasks += video_tasks("P01", steps)
    assert {t.goal for t in tasks} == {"make coffee"}
    where = {t.video: next((s.stage for s in t.steps if s.action.verb == "fold"), None) for t in tasks}
    assert where == {"P01_101": "setup", "P01_102": "setup", "P01_103": "main", "P01_104": "main", "P01_105": None}
    can = canonical.detect(tasks)[0]
    assert "fold filter" in can.detail["stages"]["setup"]  # a tie: the earlier stage
    assert all("fold filter" not in can.detail["stages"][st] for st in ("main", "finish", "cleanup"))


def test_what_is_opened_is_closed_again_or_left_open_and_storage_is_pooled():
    cupboard, drawer = ("cupboard", "fixture", True), ("drawer", "fixture", True)
    bag, cup = ("bag", "containers", False), ("cup", "crockery", False)
    tasks = []
    for n, v in enumerate(("P01_101", "P01_102", "P01_103")):
        steps = [_step(v, 0, "open", cupboard, loc="cabinet_area"), _step(v, 1, "take", cup, loc="cabinet_area"),
                 _step(v, 2, "close", cupboard, loc="cabinet_area"), _step(v, 3, "open", bag, loc="cabinet_area"),
                 _step(v, 4, "take", cup, loc="cabinet_area"), _step(v, 5, "open", drawer, loc="cabinet_area"),
                 _step(v, 6, "take", SPOON, loc="cabinet_area")]
        # the drawer is closed straight away twice, once only after six more steps; the bag never
        steps += [_step(v, 7, "close", drawer, loc="cabinet_area")] if n < 2 else \
            [_step(v, 7 + i, "put", cup, loc="cabinet_area") for i in range(6)] + [_step(v, 13, "close", drawer, loc="cabinet_area")]
        tasks += video_tasks("P01", steps)
    found = {p.key: p for p in closure.detect(tasks)}
    cup_closed = found[("cupboard", "closes")]
    assert (cup_closed.count, cup_closed.total) == (3, 3) and cup_closed.statement.startswith("Closes the cupboard again")
    assert found[("drawer", "closes")].detail == {"way": "closes", "closed": 3, "opened": 3, "prompt": 2}
    left = found[("bag", "leaves_open")]
    assert (left.count, left.total, left.exceptions) == (3, 3, []) and left.statement.startswith("Leaves the bag open")
    pooled = found[("storage", "closes")]
    assert set(pooled.objects) == {"cupboard", "drawer"} and (pooled.count, pooled.total) == (6, 6)
    assert "closure" in {p.family for p in detect_all(tasks)}


def test_tasks_and_patterns_are_written_with_the_inferred_knowledge_and_kept_stable(small_bank, tmp_path, embedder,
                                                                                 monkeypatch):
    src, _ = small_bank
    shutil.copytree(src, tmp_path / "bank", ignore=shutil.ignore_patterns(".staging"))
    bank = Bank(tmp_path / "bank")
    p = "P37"
    k = finish_participant(bank, p, embedder)
    with Store(bank.db_path(p)) as s:
        first = s.rows("tasks", participant=p)
        prefs = s.rows("preferences", participant=p)
    assert first and len(first) == len(k.tasks)
    segments = {x for r in first for x in r["segments"]}
    with Store(bank.db_path(p)) as s:
        known = load_memory(s, p).segment_ids
    assert segments <= known
    assert {json.loads(r["stages"]).keys() == {"setup", "main", "finish", "cleanup"} for r in first} == {True}
    assert k.counts()["tasks"] == len(first)
    assert {x.family for x in k.patterns} <= {"canonical", "order", "staging", "batch", "repetition", "setup", "carrier",
                                              "closure"}
    assert any(r.get("subtype") in {"order", "staging", "batch", "repetition", "setup", "carrier", "closure"} for r in prefs) or not \
        [x for x in k.patterns if x.family != "canonical"]
    monkeypatch.setattr(task_rows_module, "CHUNK_TASKS", 3)  # the rows copied a few tasks at a time
    assert len(first) > 3
    finish_participant(bank, p, embedder)  # a rebuild: the same tasks, the same ids
    with Store(bank.db_path(p)) as s:
        assert s.rows("tasks", participant=p) == first
    finish_participant(bank, p, embedder, episodic=True)
    with Store(bank.db_path(p)) as s:
        assert s.rows("tasks", participant=p) == []


def test_incremental_consolidation_writes_the_tasks_and_patterns_a_full_run_writes(small_bank, tmp_path, embedder):
    from memora_graph.consolidate.live import consolidate_bank_incremental

    src, _ = small_bank
    shutil.copytree(src, tmp_path / "bank", ignore=shutil.ignore_patterns(".staging"))
    bank = Bank(tmp_path / "bank")
    p = "P37"
    full = finish_participant(bank, p, embedder)
    with Store(bank.db_path(p)) as s:
        tasks_full = s.rows("tasks", participant=p)
    consolidate_bank_incremental(bank, [p], embedder)
    consolidate_bank_incremental(bank, [p], embedder)  # a second run reads the folds (with their tasks) back
    with Store(bank.db_path(p)) as s:
        assert s.rows("tasks", participant=p) == tasks_full
        kinds = {(r["source"], r["subtype"]) for r in s.rows("_tool_preferences", participant=p) if r["source"] == "tasks"}
    assert kinds == {("tasks", x.family) for x in full.patterns if x.family != "canonical"}


def test_compact_tasks_write_and_find_what_their_task_records_do(small_bank):
    """A batch run holds its tasks compact (steps as tuples); the Task rows and every detector's
    records are those of the same tasks as pydantic `Task`s, and each written step is a valid
    StepAction plus its stage, time and segment (a field added, dropped or retyped fails here)."""
    src, _ = small_bank
    p = "P37"
    with Store(Bank(src).db_path(p), read_only=True) as s:
        memory = load_memory(s, p)
    compact = segment_tasks(memory)
    assert compact and all(isinstance(t, CompactTask) for t in compact)
    records = [t.record() for t in compact]
    assert [CompactTask.of(r) for r in records] == compact  # live memory's folds read them back compact
    assert [Task.model_validate(r.model_dump()) for r in records] == records
    ids = memory.segment_ids
    rows = list(TaskRows(p, compact, ids))
    assert rows == list(TaskRows(p, records, ids)) and len(rows) == len(TaskRows(p, compact, ids)) == len(compact)
    for row in rows:
        for step in json.loads(row["steps"]):
            assert list(step) == [*StepAction.model_fields, "stage", "t", "segment"]
            StepAction.model_validate({k: step[k] for k in StepAction.model_fields})
            assert isinstance(step["t"], float) and step["segment"] in row["segments"]
    assert detect_all(compact) == detect_all(records)
    # the video path (live memory) makes the same tasks as records
    by_video = memory.steps_by_video()
    assert [t for v in memory.videos for t in video_tasks(p, list(by_video.get(v) or []))] == records

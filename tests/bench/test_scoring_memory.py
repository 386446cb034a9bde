"""The planning metrics' yardstick: the person's routines and preferences as consolidation has long
written them, without the task memory's records (how tasks are done), which a planner may use but
which would otherwise move the bar every plan is scored against."""

from __future__ import annotations

from memora_graph.bank import Bank
from memora_graph.bench.run import scoring_memory
from memora_graph.consolidate.task_records import TASK_SOURCES


def test_scoring_memory_leaves_the_task_records_out(small_bank):
    bank, _ = small_bank
    found = 0
    for pid in ("P09", "P37"):
        with Bank(bank).open(pid) as store:
            routines = store.rows("baseline_routines", participant=pid)
            prefs = store.rows("baseline_preferences", participant=pid)
        task_r = [r for r in routines if r["source"] in TASK_SOURCES]
        task_p = [p for p in prefs if p["source"] in TASK_SOURCES]
        found += len(task_r) + len(task_p)
        mem = scoring_memory(bank, pid)
        assert len(mem["routines"]) == len(routines) - len(task_r)
        assert len(mem["preferences"]) == len(prefs) - len(task_p)
        assert not {r["goal"] for r in task_r} & {r["goal"] for r in mem["routines"]}
    assert found, "the small bank holds task records (else this test checks nothing)"

"""What a video's tasks hold when kept for every video (live memory's folds), as `Task` records
and compact (traced with tracemalloc). usage: folds.py BANK PARTICIPANT; PYTHONPATH at the checkout."""
import sys, tracemalloc
from pathlib import Path
from memora_graph.bank import Bank
from memora_graph.consolidate.memory import load_memory
from memora_graph.consolidate.tasks import compact_video_tasks
from memora_graph.consolidate.task_records import Task
bank = Bank(Path(sys.argv[1])); p = sys.argv[2]
store = bank.open(p, read_only=True)
memory = load_memory(store, p)
by = memory.steps_by_video()
for name, f in (("pydantic Task (as before)", lambda st: [t.record() for t in compact_video_tasks(p, st)]),
                ("compact, per video (live folds now)", lambda st: compact_video_tasks(p, st))):
    tracemalloc.start()
    kept = [f(list(by[v])) for v in memory.videos]
    cur, peak = tracemalloc.get_traced_memory(); tracemalloc.stop()
    print(name, "held", round(cur / 1e6, 1), "MB", sum(len(t.steps) for ts in kept for t in ts), "steps", flush=True)
    del kept

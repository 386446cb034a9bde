"""The loop over every task (task_match.best of `bf57572`, given every row) against the task index
(retrieve/tasks.py): the same task and key objects per goal, and the time of each.

    python docs/findings/task-memory/task_index_cmp.py BANK P01,P02 [N goals]   (from the checkout: git show)
"""
import json, sys, glob, time, importlib.util, subprocess, statistics
from memora_graph.bank import Bank
from memora_graph.agent import task_match
from memora_graph.retrieve.tasks import TaskIndex
from memora_graph.perceive.lexicon import Lexicon
src = subprocess.run(["git", "show", "bf57572:memora_graph/agent/task_match.py"], capture_output=True, text=True).stdout
spec = importlib.util.spec_from_loader("old_tm", loader=None); old = importlib.util.module_from_spec(spec); exec(src, old.__dict__)
lex = Lexicon.load()
goals = ["make a cup of tea", "make toast", "put away the groceries", "wash the knife", "make coffee", "fry the egg",
         "make a salad", "wash up", "cook pasta", "prepare the vegetables", "clean the pan", "make porridge"]
for f in glob.glob("bench/data/memora-bench-calibration/planning/suites/*/*.json"):
    d = json.load(open(f)); t = d["tasks"] if isinstance(d, dict) else d
    goals += [x.get("task_query") for x in t]
goals = [g for g in dict.fromkeys(goals) if g]
bank, parts = sys.argv[1], sys.argv[2].split(",")
n = diff = 0; tn = []; to = []
for p in parts:
    s = Bank(bank).open(p, read_only=True)
    t0 = time.perf_counter(); idx = TaskIndex.read(s, p); tread = time.perf_counter() - t0
    rows = []
    for r in s.fetch("_tasks_all", participant=p):
        r = dict(r); r["steps"] = json.loads(r["steps"] or "[]"); rows.append(r)
    print(p, len(rows), "tasks; index read", round(tread, 2), "s", flush=True)
    for g in goals[: int(sys.argv[3]) if len(sys.argv) > 3 else None]:
        t0 = time.perf_counter(); a = old.best(g, rows, lex); to.append(time.perf_counter() - t0)
        t0 = time.perf_counter(); b = task_match.best(g, idx, lex); tn.append(time.perf_counter() - t0)
        n += 1
        same = (a is None and b is None) or (a is not None and b is not None and a[0]["id"] == b[0]["id"] and a[1] == b[1])
        if not same:
            diff += 1; print("DIFF", p, g, a and a[0]["id"], b and b[0]["id"])
print(f"{n} goals, {diff} differ; best() median old {statistics.median(to)*1000:.1f} ms, new {statistics.median(tn)*1000:.1f} ms; max old {max(to)*1000:.0f} new {max(tn)*1000:.0f}")

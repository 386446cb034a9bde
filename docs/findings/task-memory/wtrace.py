"""RSS (sampled every 20 ms) through `finish_participant` (as `memora consolidate`) on a COPY of a
bank, with the writer's steps marked (each COPY, the commit): which step raises the peak.
With --empty, the participant's Task rows are deleted and committed first, so the traced run
writes into an empty Task table, as a build's first consolidation does.
usage: wtrace.py BANK-COPY PARTICIPANT [--empty]; PYTHONPATH at the checkout measured."""
import sys, threading, time, resource
from pathlib import Path
bank_dir, participant, empty = sys.argv[1], sys.argv[2], "--empty" in sys.argv[3:]
def rss():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
peak = [0.0]; marks = []
def sampler():
    while True:
        peak[0] = max(peak[0], rss()); time.sleep(0.02)
threading.Thread(target=sampler, daemon=True).start()
def mark(name):
    marks.append((name, round(rss()), round(peak[0]), round(time.process_time(), 1))); print(marks[-1], flush=True); peak[0] = rss()

from memora_graph.consolidate import run as R
from memora_graph.store import Store
orig = {n: getattr(R, n) for n in ("load_memory", "infer", "write_inferred", "_write_tasks", "task_memory", "collect")}
def wrap(n):
    f = orig[n]
    def g(*a, **k):
        mark(f"before {n}"); out = f(*a, **k); mark(f"after {n}"); return out
    return g
for n in orig: setattr(R, n, wrap(n))
_copy = Store.copy
def copy(self, table, frame, *a, **k):
    mark(f"before copy {table}"); out = _copy(self, table, frame, *a, **k); mark(f"after copy {table}"); return out
Store.copy = copy
_cf = getattr(Store, "copy_file")
def copy_file(self, table, path):
    mark(f"before copy_file {table}"); out = _cf(self, table, path); mark(f"after copy_file {table}"); return out
Store.copy_file = copy_file
_tr = Store.transaction
from contextlib import contextmanager
@contextmanager
def transaction(self, *a, **k):
    with _tr(self, *a, **k) as t:
        yield t
        mark("before commit")
    mark("after commit")
Store.transaction = transaction

from memora_graph.bank import Bank
from memora_graph.embed import get_embedder
emb = get_embedder()
if empty:
    _st = Bank(Path(bank_dir)).open(participant, read_only=False)
    with _tr(_st):
        _st.run("_task_clear", participant=participant)
    _st.close()
mark("start")
k = R.finish_participant(Bank(Path(bank_dir)), participant, emb)
mark("end")
print("counts", k.counts().get("tasks"), "VmHWM MB", round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024), "CPU", round(time.process_time(), 1))

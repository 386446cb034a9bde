"""Consolidation of one participant phase by phase on a read-only bank, nothing written: CPU, wall
and RSS (sampled every 20 ms) of load_memory, the rules, the enrichment, segment_tasks, each
pattern detector, collect and the Task rows as frames. usage: trace.py BANK PARTICIPANT OUT.json
[--tm] (--tm: tracemalloc too, slower); PYTHONPATH at the checkout measured."""
import gc, json, sys, threading, time, tracemalloc, resource
from pathlib import Path

bank_dir, participant = sys.argv[1], sys.argv[2]
use_tm = "--tm" in sys.argv

def rss():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
peak = [0.0]
stop = False
def sampler():
    while not stop:
        peak[0] = max(peak[0], rss()); time.sleep(0.02)
threading.Thread(target=sampler, daemon=True).start()

from memora_graph.bank import Bank
from memora_graph.consolidate.memory import load_memory
from memora_graph.consolidate import run as R
from memora_graph import schema

out = []
def phase(name, fn):
    gc.collect(); before = rss(); peak[0] = before
    if use_tm: tracemalloc.start(); tracemalloc.reset_peak()
    c0 = time.process_time(); t0 = time.perf_counter()
    res = fn()
    c1 = time.process_time(); t1 = time.perf_counter()
    tm = tracemalloc.get_traced_memory() if use_tm else (0, 0)
    if use_tm: tracemalloc.stop()
    after = rss()
    out.append(dict(phase=name, cpu_s=round(c1 - c0, 2), wall_s=round(t1 - t0, 2), rss_before=round(before), rss_peak=round(max(peak[0], after)),
                    rss_after=round(after), tm_cur_mb=round(tm[0] / 1e6, 1), tm_peak_mb=round(tm[1] / 1e6, 1)))
    print(out[-1], flush=True)
    return res

bank = Bank(Path(bank_dir))
store = bank.open(participant, read_only=True)
memory = phase("load_memory", lambda: load_memory(store, participant))
procs = R.deterministic_processors()
cons = phase("consolidation", lambda: procs.consolidation.consolidate_streaming(memory))
enr = phase("enrichment", lambda: procs.enrichment.enrich(memory, cons))
from memora_graph.consolidate.tasks import segment_tasks
from memora_graph.consolidate.patterns import detect_all, DETECTORS
tasks = phase("segment_tasks", lambda: segment_tasks(memory))
print("tasks", len(tasks), "steps", sum(len(t.steps) for t in tasks), flush=True)
pats = []
for name, fn in DETECTORS.items():
    pats += phase(f"detect:{name}", lambda: fn(tasks))
seg_ids = memory.segment_ids
know = phase("collect", lambda: R.collect(participant, seg_ids, set(), cons, enr, "deterministic", tasks=tasks, patterns=pats))
if isinstance(know.task_rows, list):
    fr = phase("Task frame", lambda: schema.frame("Task", know.task_rows))
    print("task frame MB", round(fr.estimated_size() / 1e6, 1), "rows", fr.height)
else:
    from memora_graph.consolidate.task_rows import _chunks, CHUNK_TASKS
    def frames():
        kept = []  # what a COPY per chunk may leave Kuzu holding until the commit: every chunk's frame
        for part in _chunks(know.task_rows, CHUNK_TASKS):
            kept.append(schema.frame("Task", part))
        return kept
    fr = phase("Task frames (chunks, all kept)", frames)
    print("task frames MB", round(sum(f.estimated_size() for f in fr) / 1e6, 1), "rows", sum(f.height for f in fr))
print("VmHWM MB", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
stop = True
json.dump(out, open(sys.argv[3], "w"), indent=1)

"""ask latency on a writable server (copy of BANK): first call, p50/p95 idle, p50/p95 while a thread
remembers at 10/s, and the first ask after a batch of 100 remembers. usage: askbench.py BANK WORK"""
import glob, json, os, shutil, statistics, sys, threading, time
from pathlib import Path
bank, work = Path(sys.argv[1]), Path(sys.argv[2])
if work.exists(): shutil.rmtree(work)
shutil.copytree(bank, work)
from memora_graph.serve import MemoryService
from memora_graph.cli.perf.live import _narrations
qs = []
for f in sorted(glob.glob("/tmp/live-banks/open*/open/p01.json")):
    qs += [x["question"] for x in json.loads(Path(f).read_text())["questions"]]
qs = list(dict.fromkeys(qs))[::6][:40]
texts = _narrations("P01", 2000)
load = lambda: round(os.getloadavg()[0], 2)
out = {"code": __import__("memora_graph").__file__, "load_start": load(), "questions": len(qs)}
t0 = time.perf_counter()
svc = MemoryService(work, "P01", writable=True)
out["open_s"] = round(time.perf_counter() - t0, 2)
step = [0]
def remember():
    i = step[0]; step[0] += 1
    svc.call("remember", {"text": texts[i % len(texts)], "video": "live-perf", "start": 3.0 * i, "end": 3.0 * i + 2.5})
def ask(q):
    t = time.perf_counter(); svc.call("ask", {"question": q}); return (time.perf_counter() - t) * 1e3
pct = lambda xs, p: round(sorted(xs)[min(len(xs) - 1, int(p * len(xs)))], 1)
try:
    out["first_ask_ms"] = round(ask(qs[0]), 1)
    idle = [ask(q) for q in qs]
    out.update(ask_idle_p50_ms=pct(idle, .5), ask_idle_p95_ms=pct(idle, .95))
    stop = threading.Event(); n = [0]
    def stream():
        nxt = time.perf_counter()
        while not stop.is_set():
            remember(); n[0] += 1; nxt += 0.1; time.sleep(max(0.0, nxt - time.perf_counter()))
    th = threading.Thread(target=stream, daemon=True); ts = time.perf_counter(); th.start()
    busy = [ask(q) for q in qs]
    stop.set(); th.join()
    out.update(ask_stream_p50_ms=pct(busy, .5), ask_stream_p95_ms=pct(busy, .95),
               stream_rate=round(n[0] / (time.perf_counter() - ts), 2))
    for _ in range(100): remember()
    out["first_ask_after_100_remembers_ms"] = round(ask(qs[1]), 1)
finally:
    svc.close(); shutil.rmtree(work, ignore_errors=True)
out["load_end"] = load()
print(json.dumps(out), flush=True)

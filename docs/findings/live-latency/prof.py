"""Profile remembers through MemoryService (what perf live times), per Kùzu statement and cProfile."""
import cProfile, pstats, shutil, sys, time, collections, io
from pathlib import Path

bank_src, work, n = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3])
mode = sys.argv[4] if len(sys.argv) > 4 else "stmt"
if work.exists():
    shutil.rmtree(work)
shutil.copytree(bank_src, work)
from memora_graph.cli.perf.live import _narrations, SKIP_TOOLS
from memora_graph.cli.perf.serve import call_set
from memora_graph.serve import MemoryService
from memora_graph.store import Store

stat = collections.defaultdict(lambda: [0, 0.0, 0.0])
orig = Store._fetch
def timed(self, q, params):
    t0, c0 = time.perf_counter(), time.process_time()
    r = orig(self, q, params)
    s = stat[q.name]; s[0] += 1; s[1] += time.perf_counter() - t0; s[2] += time.process_time() - c0
    return r
Store._fetch = timed
orig_exec = Store._execute
def timed_exec(self, cypher, params=None):
    t0, c0 = time.perf_counter(), time.process_time()
    r = orig_exec(self, cypher, params)
    s = stat["EXEC " + cypher.split()[0]]; s[0] += 1; s[1] += time.perf_counter() - t0; s[2] += time.process_time() - c0
    return r
Store._execute = timed_exec

texts = _narrations("P01", 2000)
svc = MemoryService(work, "P01", writable=True)
calls = [(a, b) for a, b in call_set(svc, "P01") if a not in SKIP_TOOLS]
import os
if os.environ.get("PROF_TOOLS") == "retrieval":  # at 1,000 h the named queries scan millions of rows
    calls = [(a, b) for a, b in calls if not a.startswith("query_")]
if os.environ.get("KTHREADS"):
    svc.writer.store._conn.set_max_threads_for_exec(int(os.environ["KTHREADS"]))
for name, args in calls:
    svc.call(name, args)
i = [0]
def rem():
    k = i[0]; i[0] += 1
    svc.call("remember", {"text": texts[k % len(texts)], "video": "live-perf", "start": 3.0 * k, "end": 3.0 * k + 2.5})
for _ in range(5):
    rem()
stat.clear()
walls, cpus = [], []
pr = cProfile.Profile() if mode == "cprof" else None
if pr: pr.enable()
for _ in range(n):
    t0, c0 = time.perf_counter(), time.process_time()
    rem()
    walls.append((time.perf_counter() - t0) * 1e3); cpus.append((time.process_time() - c0) * 1e3)
if pr: pr.disable()
walls.sort(); cpus.sort()
print(f"n={n} wall p50 {walls[n//2]:.1f} p95 {walls[int(n*.95)]:.1f}  cpu p50 {cpus[n//2]:.1f} p95 {cpus[int(n*.95)]:.1f}")
tot = 0
for k, (c, w, cp) in sorted(stat.items(), key=lambda kv: -kv[1][2]):
    tot += cp
    print(f"  {k:32s} calls/rem {c/n:5.2f}  wall {w/n*1e3:6.2f} ms  cpu {cp/n*1e3:6.2f} ms")
print(f"  total store cpu/rem {tot/n*1e3:.2f} ms")
if pr:
    s = io.StringIO(); pstats.Stats(pr, stream=s).sort_stats("tottime").print_stats(30); print(s.getvalue())
svc.close()
shutil.rmtree(work)

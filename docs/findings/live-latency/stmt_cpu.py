"""LiveWriter remembers on a copy of a bank, CPU and wall per remember and per Kùzu statement
(run: stmt_cpu.py BANK WORK N; the bank is copied to WORK and removed after)."""
import shutil, sys, time, collections, os
from pathlib import Path
src, work, n = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3])
if work.exists(): shutil.rmtree(work)
shutil.copytree(src, work)
from memora_graph.cli.perf.live import _narrations
from memora_graph.form.live import LiveWriter
from memora_graph.store import Store
stat = collections.defaultdict(lambda: [0, 0.0, 0.0, 0.0, 0.0])
orig = Store._fetch
def timed(self, q, params):
    c0 = time.process_time(); t0 = time.perf_counter()
    r = orig(self, q, params)
    s = stat[q.name]; s[0] += 1; s[1] += time.process_time() - c0; s[4] += time.perf_counter() - t0
    return r
Store._fetch = timed
oe = Store._execute
def te(self, cypher, params=None):
    c0 = time.process_time(); t0 = time.perf_counter()
    r = oe(self, cypher, params)
    s = stat["EXEC " + cypher.split()[0]]; s[0] += 1; s[1] += time.process_time() - c0; s[4] += time.perf_counter() - t0
    return r
Store._execute = te
texts = _narrations("P01", 2000)
with LiveWriter(work, "P01") as wr:
    if os.environ.get("KTHREADS"): wr.store._conn.set_max_threads_for_exec(int(os.environ["KTHREADS"]))
    for k in range(5):
        wr.remember(wr.moment("live-x", 3.0 * k, 3.0 * k + 2.5, texts[k]))
    stat.clear()
    if os.environ.get("PERFWAIT"):  # for `perf record -p PID` over the measured loop only
        Path(os.environ["PERFWAIT"]).write_text(str(os.getpid())); time.sleep(3)
    cpus, walls = [], []
    for k in range(5, n + 5):
        c0 = time.process_time(); t0 = time.perf_counter()
        wr.remember(wr.moment("live-x", 3.0 * k, 3.0 * k + 2.5, texts[k % len(texts)]))
        cpus.append((time.process_time() - c0) * 1e3); walls.append((time.perf_counter() - t0) * 1e3)
cpus.sort(); walls.sort()
print(f"n={n} cpu p50 {cpus[n//2]:.1f} p95 {cpus[int(n*.95)]:.1f} wall p50 {walls[n//2]:.1f} p95 {walls[int(n*.95)]:.1f}")
tot = 0
for k, (c, cpu, comp, ex, w) in sorted(stat.items(), key=lambda kv: -kv[1][1]):
    tot += cpu
    print(f"  {k:28s} calls/rem {c/n:5.2f} cpu {cpu/n*1e3:6.2f} wall {w/n*1e3:6.2f} ms")
print(f"  total store cpu/rem {tot/n*1e3:.2f}")
shutil.rmtree(work)

"""ask CPU per call on a read-only view of BANK (P01): open, first ask, p50 / p95 over the open questions in
/tmp/live-banks/open*/open/p01.json (`memora bench generate --kind open --participants P01,P02 --seed S --out
/tmp/live-banks/openS`). usage: askprof.py BANK (main: MEMORA_TOOL_STORES=0 PYTHONPATH=/work/main)."""
import glob, json, sys, time
from pathlib import Path
from memora_graph.agent.query.answer import answer_open
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.view import MemoryView
qs = []
for f in sorted(glob.glob("/tmp/live-banks/open*/open/p01.json")):
    qs += [x["question"] for x in json.loads(Path(f).read_text())["questions"]]
qs = list(dict.fromkeys(qs))
lex = Lexicon.load()
t = time.perf_counter(); c = time.process_time()
view = MemoryView.open(sys.argv[1], "P01")
print("open", round(time.perf_counter() - t, 2), "s; cpu", round(time.process_time() - c, 2))
t = time.perf_counter(); c = time.process_time()
answer_open(view, "P01", qs[0], lex)
print("first ask", round(time.perf_counter() - t, 2), "s; cpu", round(time.process_time() - c, 2), )
cpu = []
for q in qs:
    c = time.process_time(); a = answer_open(view, "P01", q, lex); cpu.append(((time.process_time() - c) * 1e3, a.asked, q))
cpu.sort()
print("ask CPU ms p50", round(cpu[len(cpu)//2][0], 1), "p95", round(cpu[int(.95*len(cpu))][0], 1), "max", [(round(x, 1), k) for x, k, _ in cpu[-5:]])
import cProfile, pstats
sys.exit(0)
for _, _, q in cpu[-20:]: answer_open(view, "P01", q, lex)
pr.disable(); pstats.Stats(pr).sort_stats("cumulative").print_stats(18)

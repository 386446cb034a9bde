"""cProfile of `ask` on a writable MemoryService, 10 remembers before each. Usage: python
ask_after_remembers_prof.py BANK (a copy: it is written)."""
import cProfile, pstats, sys, time
from pathlib import Path
from memora_graph.serve import MemoryService
from memora_graph.form.live import Moment
bank = Path(sys.argv[1])
t0=time.perf_counter()
s = MemoryService(bank, "P01", writable=True, call_timeout=None)
print("open", round(time.perf_counter()-t0,2))
q = {"question": "After P01 takes the plate, what do they usually do next?"}
t0=time.perf_counter(); s.call("ask", q); print("first ask", round((time.perf_counter()-t0)*1000))
texts = ["take plate", "wash plate", "put plate on rack", "open fridge", "take milk", "close fridge"]
def rem(n, off):
    for i in range(n):
        t=3.0*(i+off)
        s.call("remember", {"video":"live-perf","start":t,"end":t+2.5,"text":texts[i%len(texts)]})
rem(50, 0)
ts=[]
for i in range(5):
    t0=time.perf_counter(); s.call("ask", q); ts.append(round((time.perf_counter()-t0)*1000))
print("asks after 50 remembers", ts)
pr = cProfile.Profile()
ts=[]
for k in range(5):
    rem(10, 100+10*k)
    pr.enable()
    t0=time.perf_counter(); r=s.call("ask", q); ts.append(round((time.perf_counter()-t0)*1000))
    pr.disable()
print("ask after each 10 remembers", ts)
pstats.Stats(pr).sort_stats("cumulative").print_stats(40)

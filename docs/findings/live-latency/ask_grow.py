"""Side by side in one process: the reader's log after 10 remembered segments, derived afresh
against mended from the log before. Usage: python ask_grow.py BANK (a copy; P01 read-only)."""
import json, statistics, sys, time
from pathlib import Path
from memora_graph.serve import MemoryService
from memora_graph.agent.query.log import action_log, step_log
from memora_graph.perceive.lexicon import Lexicon
s = MemoryService(Path(sys.argv[1]), "P01", writable=False, call_timeout=None)
s.call("ask", {"question": "After P01 takes the plate, what do they usually do next?"})
view = s._views["P01"]
lex = Lexicon.load()
log = action_log(view, lex)
seen = view.__dict__["_open_log_words"]
def derive(l):
    l.all.run_starts(); l.nouns; l.pairs(); l.run_keys()
derive(log)
print("steps", len(log))
texts = [("take plate", "plate", "take"), ("wash plate", "plate", "wash"), ("open fridge", "fridge", "open")]
res = {"mended": [], "afresh": []}
for r in range(7):
    segs = [{"id": f"live#{r}-{i}", "video": "P01_live", "turn": i, "t_start": 10.0 * (r * 10 + i),
             "action_breakdown": json.dumps([{"narration": texts[i % 3][0], "object": texts[i % 3][1],
                                              "action": texts[i % 3][2], "timestamp": 1.0}])} for i in range(10)]
    rows = log.rows.added(segs)
    for how in (["mended", "afresh"] if r % 2 else ["afresh", "mended"]):
        t0 = time.process_time()
        l = step_log(rows, lex, seen, log if how == "mended" else None)
        derive(l)
        res[how].append((time.process_time() - t0) * 1000)
        if how == "mended":
            new = l
    log = new
for k, v in res.items():
    print(k, "median CPU ms", round(statistics.median(v), 1), [round(x) for x in v])

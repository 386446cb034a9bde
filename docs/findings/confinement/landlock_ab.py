"""Landlock's cost on a one-shot `memora query`: the same command with the query child confined and
with `MEMORA_TEST_NO_LANDLOCK=1` (the child runs unconfined), alternated, N pairs; prints the median
wall time and the median CPU time of the process tree (user + sys of `memora` and its child).

    python docs/findings/confinement/landlock_ab.py BANK N     # BANK holds P09 (memora build BANK --participants P09,P37)
"""

import os
import resource
import statistics
import subprocess
import sys
import time

bank, n = sys.argv[1], int(sys.argv[2])
memora = os.path.join(os.path.dirname(sys.executable), "memora")
cmd = [memora, "query", bank, "MATCH (e:Entity) RETURN e.participant AS p, count(*) AS n", "--participant", "P09",
       "--json"]
res: dict[str, list[tuple[float, float]]] = {"confined": [], "unconfined": []}
for i in range(n):
    for kind in (("confined", "unconfined") if i % 2 == 0 else ("unconfined", "confined")):
        env = dict(os.environ)
        if kind == "unconfined":
            env["MEMORA_TEST_NO_LANDLOCK"] = "1"
        r0, t = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
        p = subprocess.run(["nice", "-n", "19", *cmd], env=env, capture_output=True, text=True)
        wall, r1 = time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN)
        if p.returncode:
            sys.exit(p.stderr[-300:])
        res[kind].append((wall, r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime))
for kind, runs in res.items():
    print(f"{kind}: wall median {statistics.median(w for w, _ in runs):.3f} s, "
          f"CPU median {statistics.median(c for _, c in runs):.3f} s, n={len(runs)}")

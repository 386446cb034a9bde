"""Copy a bank, remember N narrations into it with the code on PYTHONPATH, dump every node and edge (sorted, minus wall-clock stamps) as JSON lines."""
import json, shutil, sys
from pathlib import Path

src, work, n, out = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
if work.exists():
    shutil.rmtree(work)
shutil.copytree(src, work)
from memora_graph.cli.perf.live import _narrations
from memora_graph.form.live import LiveWriter
from memora_graph import schema

texts = _narrations("P01", 2000)
with LiveWriter(work, "P01") as w:
    for k in range(n):
        video = ["live-a", "live-b", "live-a", "live-c"][k % 4]
        w.remember(w.moment(video, 3.0 * k, 3.0 * k + 2.5, texts[k % len(texts)]))
import kuzu
db = kuzu.Database(str(work / "P01.kuzu"), read_only=True)
c = kuzu.Connection(db)
SKIP = {"at", "built_at", "applied_at"}
def clean(d):
    return {k: v for k, v in sorted(d.items()) if k not in SKIP and not k.startswith("_")}
lines = []
tables = c.execute("CALL show_tables() RETURN *").get_all()
for row in tables:
    name, kind = row[1], row[2]
    if kind == "NODE":
        for (x,) in c.execute(f"MATCH (x:{name}) RETURN x").get_all():
            lines.append(f"{name} " + json.dumps(clean(x), default=str, sort_keys=True))
    elif kind == "REL":
        for a, r, b in c.execute(f"MATCH (a)-[r:{name}]->(b) RETURN a.id, r, b.id").get_all():
            lines.append(f"{name} {a} -> {b} " + json.dumps(clean(r), default=str, sort_keys=True))
lines.sort()
Path(out).write_text("\n".join(lines) + "\n")
print(out, len(lines), "rows")

"""The records consolidation would write for each participant of a bank (read-only, nothing
written): Routine and Preference rows, their edges, the Task rows; one JSON file per participant
and a hash per kind. usage: records.py BANK OUTDIR P01,P02; compare two OUTDIRs with `cmp`."""
import hashlib, json, sys
from pathlib import Path
from memora_graph.bank import Bank
from memora_graph.consolidate.memory import load_memory
from memora_graph.consolidate import run as R

bank_dir, outdir, parts = sys.argv[1], Path(sys.argv[2]), sys.argv[3].split(",")
outdir.mkdir(parents=True, exist_ok=True)
bank = Bank(Path(bank_dir))
for p in parts:
    store = bank.open(p, read_only=True)
    memory = load_memory(store, p)
    ents = {r["id"] for r in store.fetch("_consolidate_entity_ids", participant=p)}
    k = R.infer(memory, ents, R.deterministic_processors())
    rec = {"routines": k.routines, "preferences": k.preferences, "supported_by": sorted(k.supported_by),
           "uses": sorted(k.uses), "about": sorted(k.about), "task_rows": list(k.task_rows),
           "counts": k.counts()}
    text = json.dumps(rec, sort_keys=True, default=str)
    (outdir / f"{p}.json").write_text(text)
    hs = {key: hashlib.sha256(json.dumps(v, sort_keys=True, default=str).encode()).hexdigest()[:12] for key, v in rec.items()}
    print(p, len(k.routines), len(k.preferences), len(k.task_rows), hs, flush=True)
    store.close()

"""What a writable server holds at 100 h: a copy of BANK opened as `MemoryService(..., writable=True,
consolidate_every=1)`, warm, one search, one background consolidation (every video: the copy has no
folds file), then `close`; VmRSS / VmHWM from /proc/self/status after each step, in MB, and the size of the
folds file the close writes (`BANK/.cache/consolidate-P01.json`).

    python docs/findings/live-latency/server_rss.py BANK-100h WORK     # BANK is copied into WORK first
"""

import shutil
import sys
from pathlib import Path


def status() -> dict[str, float]:
    out = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = round(int(value.split()[0]) / 1024, 1)
    return out


def main() -> None:
    source, work = Path(sys.argv[1]), Path(sys.argv[2])
    bank = work / "bank"
    shutil.rmtree(bank, ignore_errors=True)
    shutil.copytree(source, bank)
    from memora_graph.serve.service import MemoryService

    svc = MemoryService(bank, participant="P01", writable=True, consolidate_every=1)
    svc.warm("P01")
    svc.call("search", {"query": "knife"})
    print("after opening", status(), flush=True)
    svc.consolidator.added(1)
    svc.consolidator.wait()
    if svc.consolidator.error is not None:
        raise SystemExit(f"consolidation failed: {svc.consolidator.error}")
    svc.call("search", {"query": "knife"})
    print("after the first consolidation (every video)", status(), svc.consolidator.runs[-1].get("total"), "s",
          flush=True)
    svc.close()
    folds = bank / ".cache" / "consolidate-P01.json"
    size = f"{folds.stat().st_size / 1e6:.1f} MB" if folds.exists() else "not written"
    print("after close (folds file written)", status(), "folds file", size, flush=True)
    shutil.rmtree(bank, ignore_errors=True)


if __name__ == "__main__":
    main()

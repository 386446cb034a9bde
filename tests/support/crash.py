"""Kill a live writer (SIGKILL) after N acknowledged moments, and count what survives.

Used by tests/form/test_live_durability.py, and runnable to measure larger N (nice it):

    PYTHONPATH=. nice -n 19 .venv/bin/python tests/support/crash.py --moments 5000 --moments 20000

For each N: a fresh bank, `memora remember BANK --participant P09 --jsonl -` fed P09's own
narrations (bundled EPIC annotations) as new videos, SIGKILL once N are acknowledged (the log size
then), then the time a new writer takes to open it (replaying the log: what `memora remember` and
`memora serve --writable` do first), the acknowledged keys not found, and `memora verify`.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def narrations(participant: str, n: int) -> list[dict]:
    """`n` moments of the participant's own narrations, 200 to a video, 3 s apart."""
    from memora_graph.perceive.annotations import load_annotations

    texts = load_annotations(participants=[participant])["narration"].to_list()
    return [{"video": f"live-{i // 200}", "start": (i % 200) * 3.0, "end": (i % 200) * 3.0 + 2.0,
             "text": texts[i % len(texts)]} for i in range(n)]


def writer(bank: Path, participant: str, *options: str, stderr=None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "memora_graph.cli", "remember", str(bank), "--participant",
                             participant, "--jsonl", "-", *options],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=stderr or subprocess.DEVNULL,
                            text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})


def _feed(proc, todo: list[dict]) -> None:
    """Write `todo` to a writer's stdin, one JSON line each, until it is killed."""
    try:
        for m in todo:
            proc.stdin.write(json.dumps(m) + "\n")
            proc.stdin.flush()
    except (BrokenPipeError, OSError, ValueError):
        pass


def kill_after(bank: Path, participant: str, todo: list[dict], acks: int | None = None, *options: str,
               log_bytes: int | None = None) -> dict:
    """Feed `todo` to a writer and SIGKILL it once `acks` moments are acknowledged (or once its
    write-ahead log holds `log_bytes`). Returns the acknowledged keys -> segments, the log's
    size at the kill and the seconds it ran."""
    err = open(Path(bank).parent / f"{Path(bank).name}-remember-stderr.txt", "a")
    proc = writer(bank, participant, *options, stderr=err)
    err.close()

    threading.Thread(target=_feed, args=(proc, todo), daemon=True).start()
    wal = Path(bank) / f"{participant}.kuzu.wal"
    acked: dict[str, str] = {}
    t0 = time.perf_counter()
    for line in proc.stdout:
        got = json.loads(line)
        acked[got["key"]] = got["segment"]
        if acks is not None and len(acked) >= acks:
            break
        if log_bytes is not None and wal.exists() and wal.stat().st_size >= log_bytes:
            break
    at_kill = wal.stat().st_size if wal.exists() else 0
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    return {"acked": acked, "log_bytes": at_kill, "seconds": time.perf_counter() - t0}


def kill_in_checkpoint(bank: Path, participant: str, todo: list[dict], *options: str, timeout_s: float = 120) -> dict:
    """Feed `todo` to a writer (`options`: its checkpoint schedule) and SIGKILL it inside a
    checkpoint, once its record is in the log: the shadow file holds pages and the log has grown
    since it did (no moment commits during a checkpoint); watched every millisecond from the first
    acknowledged moment on. Returns the acknowledged keys -> segments and whether the kill came
    there (False: `timeout_s` passed, or the writer ended, first)."""
    proc = writer(bank, participant, *options)
    acked: dict[str, str] = {}

    def read() -> None:
        for line in proc.stdout:
            got = json.loads(line)
            acked[got["key"]] = got["segment"]

    def size(f: Path) -> int:
        try:
            return f.stat().st_size
        except FileNotFoundError:
            return 0

    reader = threading.Thread(target=read, daemon=True)
    threading.Thread(target=_feed, args=(proc, todo), daemon=True).start()
    reader.start()
    shadow, wal = (Path(bank) / f"{participant}.kuzu{s}" for s in (".shadow", ".wal"))
    t_end, log_at_shadow, during = time.monotonic() + timeout_s, None, False
    while time.monotonic() < t_end and proc.poll() is None:
        if not acked:  # (creating the participant checkpoints too: a kill then acknowledged nothing)
            time.sleep(0.01)
            continue
        if size(shadow) == 0:
            log_at_shadow = None
        elif log_at_shadow is None:
            log_at_shadow = size(wal)
        elif size(wal) > log_at_shadow:
            during = True
            break
        time.sleep(0.001)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    reader.join(10)
    return {"acked": dict(acked), "during": during}


def _children_cpu() -> float:
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def stored_keys(bank: Path, participant: str) -> tuple[dict[str, str], float]:
    """Open the participant's memory with a new writer (replaying any log), and its Remembered
    keys -> segments; with the seconds the writer took to open."""
    from memora_graph.form.live import LiveWriter

    c0, k0 = time.process_time(), _children_cpu()
    t0 = time.perf_counter()
    with LiveWriter(bank, participant) as memory:
        opened = time.perf_counter() - t0
        stored_keys.cpu_s = time.process_time() - c0 + _children_cpu() - k0
        rows = memory.store.query("MATCH (r:Remembered) WHERE r.participant = $p RETURN r.id AS id, "
                                  "r.segment AS segment", {"p": participant}).to_dicts()
    return {r["id"]: r["segment"] for r in rows}, opened


def measure(n: int, work: Path, participant: str = "P09", log_mb: float | None = None) -> dict:
    """Kill a writer after `n` acknowledged moments (or, with `log_mb`, once its log holds that
    many MB: the largest log the default schedule allows is just under 4 MB), then reopen."""
    from memora_graph.integrity.verify import verify_bank

    bank = work / (f"crash-{n}" if log_mb is None else f"crash-log-{log_mb:g}")
    if bank.exists():
        import shutil

        shutil.rmtree(bank)
    got = kill_after(bank, participant, narrations(participant, n + 20), None if log_mb else n,
                     log_bytes=int(log_mb * 1e6) if log_mb else None)
    db = bank / f"{participant}.kuzu"
    db_mb = db.stat().st_size / 1e6
    stored, opened = stored_keys(bank, participant)
    lost = [k for k, s in got["acked"].items() if stored.get(k) != s]
    report = verify_bank(bank)
    return {"moments": len(got["acked"]), "log_mb_at_kill": round(got["log_bytes"] / 1e6, 2),
            "db_mb_at_kill": round(db_mb, 1), "write_s": round(got["seconds"], 1), "reopen_s": round(opened, 2),
            "reopen_cpu_s": round(stored_keys.cpu_s, 2),
            "lost": len(lost), "verify": "ok" if report.ok else "; ".join(p for r in report.rows for p in r["problems"])}


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--moments", type=int, action="append", default=[])
    ap.add_argument("--log-mb", type=float, help="kill once the log holds this many MB (at most --moments[0] or 5,000)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/memora-crash"))
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    for n in args.moments or [5000]:
        load = os.getloadavg()[0]
        row = measure(n, args.work, log_mb=args.log_mb)
        print(json.dumps({**row, "load_start": round(load, 2), "load_end": round(os.getloadavg()[0], 2)}), flush=True)

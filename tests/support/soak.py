"""Soak a writable server with kill -9: 3 writers and 2 readers over HTTP, random SIGKILLs.

Used by the slow test in tests/form/test_live_durability.py, and runnable (nice it):

    PYTHONPATH=. nice -n 19 .venv/bin/python tests/support/soak.py --seconds 300 --kills 5
    PYTHONPATH=. nice -n 19 .venv/bin/python tests/support/soak.py --kills 10 --checkpoint-mb 0.3

(the second checkpoints within every round, so that kills land inside checkpoints too).

Each round starts `memora serve BANK --participant P09 --writable --transport http --token T`
(timed: the restart, its writer replaying the log the last kill left), runs 3 writer threads
(`remember` calls, each acknowledged one recorded by its key) and 2 reader threads (retrieval
tools) for a random 4-15 s, and kills the server with SIGKILL. After every kill `memora verify`
must find nothing but the interrupted writer and a recoverable log (`after_kill_ok`, by the kinds
of its problems); after every other kill the documented repair (`memora verify BANK --accept P09`)
runs and `verify` must then pass, otherwise the next server replays the log itself. At the end a
server is stopped cleanly, `verify` must pass, and every acknowledged write must be found by its key.
"""

from __future__ import annotations

import json
import os
import random
import re
import statistics
import threading
import time
from pathlib import Path

TOKEN = "soak-token"
QUERIES = ["knife", "plate", "fridge", "cup", "pan", "tap", "spoon", "drawer"]


class _Round:
    def __init__(self, url: str, texts: list[str], next_start: list[float], rng: random.Random):
        self.url, self.texts, self.next_start, self.rng = url, texts, next_start, rng
        self.stop = threading.Event()
        self.acked: dict[str, str] = {}
        self.reads = 0
        self.read_errors_alive = 0  # reader errors while the server was up
        self.lock = threading.Lock()

    def _client(self):
        from mcp import Client
        from mcp.client.streamable_http import create_mcp_http_client, streamable_http_client

        return Client(streamable_http_client(self.url, http_client=create_mcp_http_client(
            headers={"Authorization": f"Bearer {TOKEN}"})))

    def writer(self, w: int) -> None:
        import anyio

        async def run() -> None:
            async with self._client() as client:
                while not self.stop.is_set():
                    start = self.next_start[w]
                    self.next_start[w] += 3.0
                    text = self.texts[int(start / 3.0 + 7 * w) % len(self.texts)]
                    res = await client.call_tool("remember", {"text": text, "video": f"soak-w{w}", "start": start,
                                                              "end": start + 2.0})
                    if res.is_error:
                        raise RuntimeError(str(res.content))
                    with self.lock:
                        self.acked[res.structured_content["key"]] = res.structured_content["segment"]

        try:
            anyio.run(run)
        except BaseException:  # noqa: BLE001 - the server was killed under it
            pass

    def reader(self, r: int) -> None:
        import anyio

        async def run() -> None:
            async with self._client() as client:
                while not self.stop.is_set():
                    q = self.rng.choice(QUERIES)
                    tool, args = (("search_objects", {"query": q}) if r == 0 else
                                  ("get_object_history", {"object_query": q}))
                    res = await client.call_tool(tool, args)
                    with self.lock:
                        self.reads += 1
                        self.read_errors_alive += bool(res.is_error) and not self.stop.is_set()

        try:
            anyio.run(run)
        except BaseException:  # noqa: BLE001
            pass


def _cpu(pid: int) -> float:
    """CPU seconds a process and its waited-for children (the replay's child) used so far."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return sum(int(f) for f in fields[11:15]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


# What verify may find after a live writer is killed (by problem kind: memora_graph/integrity/verify.py
# KINDS, LOG_STATES): the interrupted writer, its rows per table past the last record, and a log that
# is absent (checkpointed just before), empty (a kill as a checkpoint removed it), replayed read-only,
# or an interrupted checkpoint (shadow pages) that replays read-write on a copy; or a log Kùzu cannot
# replay (a kill early in a checkpoint) with the intake journal that re-applies what it held (form/intake.py).
AFTER_KILL_KINDS = {"live_interrupted", "tables_differ", "journal"}
AFTER_KILL_LOGS = {"none", "empty", "replayed", "checkpoint", "cannot be replayed"}


def after_kill_ok(row: dict) -> bool:
    """Whether a verify row is one of the states a kill -9 of the live writer legally leaves."""
    return ("live_interrupted" in row["kinds"] and set(row["kinds"]) <= AFTER_KILL_KINDS
            and row["log"] in AFTER_KILL_LOGS)


def soak(bank: Path, seconds: float, kills: int = 5, seed: int = 38, participant: str = "P09",
         echo=print, server_options: tuple[str, ...] = ()) -> dict:
    """The soak (see the module); `server_options` go to every `memora serve` (e.g. a checkpoint
    schedule: `("--checkpoint-mb", "0.5")` checkpoints within every round, so kills land in them)."""
    import signal

    from memora_graph.cli.perf.serve import ServerProcess
    from memora_graph.errors import BankError
    from memora_graph.integrity.verify import accept, verify_bank
    from support.crash import narrations, stored_keys

    rng = random.Random(seed)
    texts = [m["text"] for m in narrations(participant, 400)]
    next_start = [0.0, 0.0, 0.0]
    acked: dict[str, str] = {}
    restarts, cpu, replays, problems, logs, states, reads = [], [], [], [], [], [], 0
    killed = 0
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end or killed < kills:
        t0 = time.perf_counter()
        server = ServerProcess(bank, participant, "--writable", "--token", TOKEN, *server_options)
        restarts.append(time.perf_counter() - t0)
        cpu.append(_cpu(server.proc.pid))
        replays += [float(m.group(1)) for line in server.lines if (m := re.search(r"replayed in ([\d.]+) s", line))]
        rnd = _Round(server.url, texts, next_start, rng)
        threads = [threading.Thread(target=rnd.writer, args=(w,), daemon=True) for w in range(3)]
        threads += [threading.Thread(target=rnd.reader, args=(r,), daemon=True) for r in range(2)]
        for t in threads:
            t.start()
        time.sleep(rng.uniform(4.0, 15.0))
        wal = bank / f"{participant}.kuzu.wal"
        os.kill(server.proc.pid, signal.SIGKILL)
        server.proc.wait()
        rnd.stop.set()
        for t in threads:
            t.join(30)
        killed += 1
        acked.update(rnd.acked)
        reads += rnd.reads
        logs.append(wal.stat().st_size if wal.exists() else 0)
        if rnd.read_errors_alive:
            problems.append(f"round {killed}: {rnd.read_errors_alive} reads failed while the server was up")
        row = verify_bank(bank).rows[0]
        states.append(row.get("log"))
        if not after_kill_ok(row):
            problems.append(f"after kill {killed}: verify: {row}")
        if killed % 2 == 0:  # the documented repair, then verify must pass
            try:
                accept(bank, participant)
            except BankError as exc:  # the log cannot be replayed: the bank cannot go on (nor be counted)
                problems.append(f"after kill {killed}: verify --accept: {exc}")
                return {"kills": killed, "acknowledged": len(acked), "lost": None, "reads": reads,
                        "log_mb_at_kills": [round(b / 1e6, 2) for b in logs], "log_at_kills": states,
                        "problems": problems, "lost_keys": []}
            report = verify_bank(bank)
            if not report.ok:
                problems.append(f"after kill {killed} and --accept: verify: {report.rows}")
        echo(f"kill {killed}: {len(rnd.acked)} writes acknowledged ({len(acked)} in all), {rnd.reads} reads, log "
             f"{logs[-1] / 1e6:.1f} MB (verify: {row['log']}); restart took {restarts[-1]:.1f} s ({cpu[-1]:.1f} CPU-s)")
    t0 = time.perf_counter()
    server = ServerProcess(bank, participant, "--writable", "--token", TOKEN, *server_options)
    restarts.append(time.perf_counter() - t0)
    server.stop()
    report = verify_bank(bank)
    if not report.ok:
        problems.append(f"after the last clean stop: verify: {report.rows}")
    stored, _ = stored_keys(bank, participant)
    lost = sorted(k for k, s in acked.items() if stored.get(k) != s)
    return {"kills": killed, "acknowledged": len(acked), "lost": len(lost), "reads": reads,
            "restart_s_median": round(statistics.median(restarts), 2), "restart_s_max": round(max(restarts), 2),
            "restarts_s": [round(r, 2) for r in restarts], "restart_cpu_s": [round(c, 2) for c in cpu],
            "replays_s": replays, "log_mb_at_kills": [round(b / 1e6, 2) for b in logs],
            "log_at_kills": states,
            "problems": problems, "lost_keys": lost[:10]}


if __name__ == "__main__":
    import argparse
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=300)
    ap.add_argument("--kills", type=int, default=5)
    ap.add_argument("--bank", type=Path, default=Path("/tmp/memora-soak/bank"))
    ap.add_argument("--checkpoint-mb", help="the server's checkpoint bound (default: its own, 4 MB)")
    args = ap.parse_args()
    if args.bank.exists():
        import shutil

        shutil.rmtree(args.bank)
    load = os.getloadavg()[0]
    out = soak(args.bank, args.seconds, args.kills,
               server_options=("--checkpoint-mb", args.checkpoint_mb) if args.checkpoint_mb else ())
    print(json.dumps({**out, "load_start": round(load, 2), "load_end": round(os.getloadavg()[0], 2)}))

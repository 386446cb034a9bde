"""Participants built side by side in worker processes give the same bank as one at a time, and a
killed build leaves no worker behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from memora_graph.bank import Bank
from memora_graph.pipeline import auto_jobs, build_bank
from memora_graph.store import Store

MEMORA = [sys.executable, "-m", "memora_graph.cli"]


def test_auto_jobs():
    assert auto_jobs(1) == 1 and auto_jobs(3) == 1  # a second model load does not pay off for a couple
    assert auto_jobs(18) == min(os.cpu_count() or 1, 4)


def test_parallel_build_matches_the_serial_one(small_bank, tmp_path):
    path, serial = small_bank
    res = build_bank(tmp_path / "bank", ["P09", "P37"], jobs=2)
    assert res.jobs == 2 and [r.participant for r in res.participants] == ["P09", "P37"]
    for a, b in zip(res.participants, serial.participants):
        assert a.counts == b.counts and a.decisions == b.decisions
    got, want = Bank(tmp_path / "bank").manifest(), Bank(path).manifest()
    assert got["participants"].keys() == want["participants"].keys()  # no manifest update lost
    for p in ("P09", "P37"):
        assert got["participants"][p]["counts"] == want["participants"][p]["counts"]
    assert got["consolidated"] and got["condition"] == "memora_full"
    phases = res.phases()
    assert abs(sum(phases.values()) - 2 * res.wall_seconds) < 1e-6 and "workers idle" in phases
    assert res.model_seconds > 0 and set(res.embed_threads) == {1}  # one torch thread per worker
    assert 0 < res.graph_share < 1


def _staged(bank, p):
    from memora_graph.form.staging import Staging

    return Staging(bank / ".staging" / p).entries()


def test_killed_parallel_build_leaves_no_worker_and_resumes(tmp_path):
    bank = tmp_path / "killed"
    proc = subprocess.Popen([*MEMORA, "build", str(bank), "--participants", "P07,P37", "--jobs", "2", "--quiet"],
                            env={**os.environ, "PYTHONUNBUFFERED": "1"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.time() + 180
    while len(_staged(bank, "P07")) < 2 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, "build finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    time.sleep(2)
    for p in ("P07", "P37"):  # a worker still running would hold its database's lock (read-only opens too)
        db = Bank(bank).db_path(p)
        if db.exists():
            Store(db).close()
    resumed = build_bank(bank, ["P07", "P37"], jobs=1)
    assert resumed.participants[0].videos_skipped >= 2
    with Bank(bank).open("P07") as s:
        ids = s.query("MATCH (x:StateEvent) RETURN x.id AS id")["id"]
        assert ids.n_unique() == ids.len()
    assert not _staged(bank, "P07") and not _staged(bank, "P37")

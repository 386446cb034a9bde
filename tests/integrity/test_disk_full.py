"""A full disk is a clear error within seconds, never a hang (Kùzu 0.11.3 spins at 100% CPU in
its rollback when a database is closed after a failed write). The bank lives on a small tmpfs
mounted for the test (needs root: CAP_SYS_ADMIN); elsewhere these tests skip, saying why."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import pytest
from support.corrupt import ROOT, memora

from memora_graph.store import free_bytes


@pytest.fixture()
def small_fs(tmp_path):
    """Mount a tmpfs of the size asked for; unmounted afterwards."""
    mounts = []

    def mount(mb: int) -> Path:
        where = tmp_path / f"fs{len(mounts)}"
        where.mkdir()
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={mb}m", "tmpfs", str(where)], capture_output=True,
                           text=True)
        if r.returncode != 0:
            pytest.skip(f"cannot mount a small tmpfs here ({r.stderr.strip() or 'mount failed'}); the disk-full "
                        "tests need root (CAP_SYS_ADMIN)")
        mounts.append(where)
        return where

    yield mount
    for m in mounts:
        subprocess.run(["umount", "-l", str(m)], capture_output=True)


class FullWatch:
    """Records when the filesystem under `path` first had (almost) nothing left."""

    def __init__(self, path: Path):
        self.path, self.at, self._stop = path, None, threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            free = free_bytes(self.path)
            if free is not None and free < (1 << 20) and self.at is None:
                self.at = time.monotonic()
            time.sleep(0.01)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def _one_participant_bank(small_bank, dest: Path, p: str = "P09") -> Path:
    src, _ = small_bank
    dest.mkdir()
    shutil.copy(src / f"{p}.kuzu", dest / f"{p}.kuzu")
    data = json.loads((src / "manifest.json").read_text())
    data["participants"] = {p: data["participants"][p]}
    (dest / "manifest.json").write_text(json.dumps(data))
    return dest


def test_a_write_that_fills_the_disk_stops_with_a_clear_error(small_bank, small_fs):
    fs = small_fs(23)  # the 20 MB database and ~3 MB to spare
    bank = _one_participant_bank(small_bank, fs / "bank")
    fill = "UNWIND range(1, 400000) AS i CREATE (:Participant {id: 'x' + string(i), participant: 'P09'})"
    watch = FullWatch(fs)
    t0 = time.monotonic()
    r = memora("query", bank, fill, "--participant", "P09", "--write", timeout=120)
    end = time.monotonic()
    watch.stop()
    out = r.stdout + r.stderr
    assert r.returncode == 1, out
    assert "no space left on device" in out and "P09.kuzu" in out and "Traceback" not in out
    assert watch.at is not None
    print(f"disk full -> exit: {end - watch.at:.2f} s (whole command {end - t0:.2f} s)")
    assert end - watch.at < 5.0
    # the write never committed: readers are told it did not finish, and the file is what was recorded
    v = memora("verify", bank, "--json")
    assert v.returncode == 1
    row = json.loads(v.stdout)[0]
    assert row["hash"] == "ok" and row["write"].startswith("interrupted write")


def test_a_build_larger_than_the_free_space_is_refused_before_any_work(small_fs):
    fs = small_fs(20)
    t0 = time.monotonic()
    r = memora("build", fs / "bank", "--participants", "P04", "--quiet")
    elapsed = time.monotonic() - t0
    out = r.stdout + r.stderr
    assert r.returncode == 1, out
    assert "no space left on device for this build (needed about" in out and "MB free" in out
    assert not (fs / "bank").exists()  # nothing written
    assert elapsed < 10  # no model was loaded


@pytest.mark.slow
def test_a_disk_that_fills_during_a_build_stops_it_within_seconds(small_fs):
    """Another process takes the last free space while P09 builds: the build stops with the
    error (and its estimate) within seconds of the disk filling, and leaves nothing of P09."""
    fs = small_fs(64)
    bank = fs / "bank"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("MEMORA_NO_VERIFY", None)
    proc = subprocess.Popen([sys.executable, "-m", "memora_graph.cli", "build", str(bank), "--participants", "P09",
                             "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    deadline = time.monotonic() + 240
    staging = bank / ".staging" / "P09"
    while time.monotonic() < deadline and proc.poll() is None and not (staging.is_dir() and any(staging.iterdir())):
        time.sleep(0.02)
    assert proc.poll() is None, "the build finished before the disk could be filled"
    with open(fs / f"filler-{uuid.uuid4().hex}", "wb") as fh:  # everything that is left
        try:
            while True:
                fh.write(b"\0" * (1 << 20))
                fh.flush()
        except OSError:
            pass
    full_at = time.monotonic()
    try:
        out, _ = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the build hung on a full disk")
    stopped = time.monotonic() - full_at
    print(f"disk full -> exit: {stopped:.2f} s")
    assert proc.returncode == 1, out
    assert "no space left on device (needed about" in out and "Traceback" not in out, out
    assert stopped < 5.0
    assert not list(bank.glob("P09.kuzu*")) and not staging.exists()

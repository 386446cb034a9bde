"""A probe (the child process that opens a database read-only before a writer trusts it) ends with
the process that asked for it: a writer killed with kill -9 during recovery must not leave a probe
holding the database, which the next writer would find "busy" (seen as a rare failure of the
22-kill live-memory test under load)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

PARENT = r"""
import subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c", sys.argv[1], str(__import__("os").getpid())])
print(child.pid, flush=True)
time.sleep(120)
"""
CHILD = r"""
import sys, time
from memora_graph.files import die_with_parent
die_with_parent(int(sys.argv[1]))
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(") ")[-1][0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_probe_child_dies_with_the_process_that_asked_for_it():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    parent = subprocess.Popen([sys.executable, "-c", PARENT, CHILD], stdout=subprocess.PIPE, text=True, env=env)
    child = int(parent.stdout.readline())
    time.sleep(1.0)  # the child is past die_with_parent
    assert _alive(child)
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 10
    while _alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    gone = not _alive(child)
    if not gone:
        os.kill(child, signal.SIGKILL)
    assert gone, "the child outlived its killed parent"


def test_a_child_whose_parent_is_already_gone_exits_at_once():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    # a parent pid that is not ours: die_with_parent sees it re-parented and leaves
    res = subprocess.run([sys.executable, "-c", CHILD, "1"], env=env, timeout=60)
    assert res.returncode == 1

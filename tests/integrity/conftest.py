"""A pristine copy of the small bank per test, and the CLI in a subprocess (a crash there shows
as a negative return code instead of taking pytest down)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def memora(*args, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH", "")]))}
    env.pop("MEMORA_NO_VERIFY", None)
    return subprocess.run([sys.executable, "-m", "memora_graph.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.fixture()
def bank(small_bank, tmp_path) -> Path:
    path, _ = small_bank
    copy = tmp_path / "bank"
    shutil.copytree(path, copy)
    return copy

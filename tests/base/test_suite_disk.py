"""The suite keeps no passing test's temporary bank: ~700 tests copy banks into tmp_path (~11 GB kept at
once otherwise, which filled a CI machine's disk midway through a run and failed the tests after it).
pyproject's `tmp_path_retention_policy = "failed"` removes a passing test's tmp_path as it ends and
keeps a failing one's to look at; this runs pytest under the project's own configuration to check it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

TESTS = '''
def test_passes(tmp_path):
    (tmp_path / "bank.kuzu").write_bytes(b"x" * 1024)

def test_fails(tmp_path):
    (tmp_path / "bank.kuzu").write_bytes(b"x" * 1024)
    assert False
'''


def test_a_passing_tests_tmp_path_is_removed_and_a_failing_ones_kept(tmp_path):
    (tmp_path / "test_two.py").write_text(TESTS)
    base = tmp_path / "base"
    run = subprocess.run([sys.executable, "-m", "pytest", "-c", str(ROOT / "pyproject.toml"), "--rootdir", str(tmp_path),
                          f"--basetemp={base}", "-p", "no:cacheprovider", "-q", "-m", "", str(tmp_path / "test_two.py")],
                         capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert "1 failed, 1 passed" in run.stdout, run.stdout + run.stderr
    kept = {p.parent.name for p in base.rglob("bank.kuzu")}
    assert kept == {"test_fails0"}, kept

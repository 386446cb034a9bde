"""A pristine copy of the small bank per test (the session's bank stays untouched)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest


@pytest.fixture()
def bank(small_bank, tmp_path) -> Path:
    path, _ = small_bank
    copy = tmp_path / "bank"
    shutil.copytree(path, copy)
    return copy

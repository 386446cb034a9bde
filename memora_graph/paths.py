"""Where the project's bundled files live: data, schema and named queries.

In the repository they sit at the root (`schema/`, `queries/`, `bench/data/`); the wheel carries the same
folders inside the package as `memora_graph/_bundled/` (setup.py maps them), found here with
importlib.resources. An installed package reads its own copy; a checkout (editable install, or PYTHONPATH)
reads the repository's folders. `MEMORA_DATA_DIR` points the data at another copy (for example the full
EPIC release).
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[1]


def _bundled(name: str, in_checkout: Path) -> Path:
    """The folder `name` as the wheel installed it, else the checkout's own."""
    packaged = resources.files("memora_graph") / "_bundled" / name
    if packaged.is_dir():
        return Path(str(packaged))
    return in_checkout


SCHEMA_DIR = _bundled("schema", PROJECT_ROOT / "schema")
QUERIES_DIR = _bundled("queries", PROJECT_ROOT / "queries")
BUNDLED_DATA_DIR = _bundled("data", PROJECT_ROOT / "bench" / "data")


def data_dir() -> Path:
    return Path(os.environ.get("MEMORA_DATA_DIR", BUNDLED_DATA_DIR))


def epic_dir() -> Path:
    return data_dir() / "epic-kitchens-100"


def calibration_dir() -> Path:
    return data_dir() / "memora-bench-calibration"


def default_annotations() -> Path:
    return epic_dir() / "extension_narrations.csv"

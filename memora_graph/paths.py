"""Where the project's bundled files live: data, schema and named queries.

The README installs the project in editable mode, so these resolve inside the checkout.
`MEMORA_DATA_DIR` points the data at another copy (for example the full EPIC release).
"""

from __future__ import annotations

import os
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SCHEMA_DIR = PROJECT_ROOT / "schema"
QUERIES_DIR = PROJECT_ROOT / "queries"


def data_dir() -> Path:
    return Path(os.environ.get("MEMORA_DATA_DIR", PROJECT_ROOT / "bench" / "data"))


def epic_dir() -> Path:
    return data_dir() / "epic-kitchens-100"


def calibration_dir() -> Path:
    return data_dir() / "memora-bench-calibration"


def default_annotations() -> Path:
    return epic_dir() / "extension_narrations.csv"

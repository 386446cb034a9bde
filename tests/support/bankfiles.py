"""What a test that reads a bank compares before and after: each file's sha256, the manifest's less
the records of derived files (bank/derived.py), which a reader writes when it computes them (the
tool stores on first use), as it writes the files themselves under BANK/.cache/."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path


def without_derived(manifest: dict) -> dict:
    data = dict(manifest)
    data.pop("derived", None)
    data["participants"] = {p: {k: v for k, v in e.items() if k != "derived"}
                            for p, e in data.get("participants", {}).items()}
    return data


def file_sha256(path: Path) -> str:
    """A file's sha256; for a bank's manifest.json, that of its content less the derived records."""
    data = path.read_bytes()
    if path.name == "manifest.json":
        try:
            data = json.dumps(without_derived(json.loads(data)), sort_keys=True).encode()
        except (ValueError, AttributeError, TypeError):
            pass
    return hashlib.sha256(data).hexdigest()

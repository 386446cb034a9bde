"""The corruption corpus: ways a bank's files get damaged or tampered with, each applied to a
copy of a built bank. Every case damages participant P09 (or the bank around it); the test
then runs a command that reads P09 and expects a clear error naming the file, never a crash
(negative return code from a signal) and never an answer (exit 0)."""

from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PAGE = 4096


def memora(*args, timeout: float = 120, env: dict | None = None) -> subprocess.CompletedProcess:
    """The CLI in a subprocess: a Kùzu crash shows as a negative return code."""
    full = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH", "")]))}
    full.pop("MEMORA_NO_VERIFY", None)
    full.update(env or {})
    return subprocess.run([sys.executable, "-m", "memora_graph.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=full)


def _edit(db: Path, old: bytes, new: bytes, nth: int = 0) -> None:
    data = bytearray(db.read_bytes())
    at = -1
    for _ in range(nth + 1):
        at = data.find(old, at + 1)
    assert at >= 0, f"{old!r} not in {db}"
    data[at:at + len(old)] = new
    db.write_bytes(bytes(data))


def truncate(bank: Path) -> str:
    db = bank / "P09.kuzu"
    with open(db, "r+b") as fh:
        fh.truncate(db.stat().st_size // 2)
    return "P09.kuzu"


def zero_fill(bank: Path) -> str:
    db = bank / "P09.kuzu"
    with open(db, "r+b") as fh:
        fh.seek(db.stat().st_size // 3)
        fh.write(b"\0" * 16 * PAGE)
    return "P09.kuzu"


def damaged_pages(bank: Path) -> str:
    """20 random pages overwritten with random bytes (crashed Kùzu with SIGSEGV before)."""
    db = bank / "P09.kuzu"
    rng = random.Random(7)
    n = db.stat().st_size // PAGE
    with open(db, "r+b") as fh:
        for page in rng.sample(range(1, n), 20):
            fh.seek(page * PAGE)
            fh.write(rng.randbytes(PAGE))
    return "P09.kuzu"


def narration_edit(bank: Path) -> str:
    _edit(bank / "P09.kuzu", b"turn on stove", b"turn on glove")
    return "P09.kuzu"


def state_edit(bank: Path) -> str:
    _edit(bank / "P09.kuzu", b"held", b"gone", nth=3)
    return "P09.kuzu"


def edit_op_id(bank: Path) -> str:
    _edit(bank / "P09.kuzu", b"P09:op0000001", b"P09:op0000009")
    return "P09.kuzu"


def garbled_text_page(bank: Path) -> str:
    """The page holding a narration, its letters scrambled (the page stays readable to Kùzu)."""
    db = bank / "P09.kuzu"
    data = bytearray(db.read_bytes())
    page = data.find(b"turn on stove") // PAGE * PAGE
    rng = random.Random(3)
    for i in range(page, page + PAGE):
        if 97 <= data[i] <= 122:
            data[i] = rng.randint(97, 122)
    db.write_bytes(bytes(data))
    return "P09.kuzu"


def empty_file(bank: Path) -> str:
    (bank / "P09.kuzu").write_bytes(b"")
    return "P09.kuzu"


def missing_file(bank: Path) -> str:
    (bank / "P09.kuzu").unlink()
    return "P09.kuzu"


def foreign_wal(bank: Path) -> str:
    """A write-ahead log of P37's database placed next to P09's (crashed Kùzu with SIGSEGV before)."""
    other = bank.parent / "wal-source.kuzu"
    shutil.copy(bank / "P37.kuzu", other)
    code = ("import os, sys, kuzu; db = kuzu.Database(sys.argv[1], auto_checkpoint=False); "
            "c = kuzu.Connection(db); c.execute(\"MATCH (e:Entity) SET e.state = 'zzz'\"); os._exit(0)")
    subprocess.run([sys.executable, "-c", code, str(other)], check=True)
    shutil.copy(other.with_name(other.name + ".wal"), bank / "P09.kuzu.wal")
    return "P09.kuzu.wal"


def shadow_file(bank: Path) -> str:
    (bank / "P09.kuzu.shadow").write_bytes(os.urandom(3 * PAGE))
    return "P09.kuzu.shadow"


def swapped_files(bank: Path) -> str:
    a, b, tmp = bank / "P09.kuzu", bank / "P37.kuzu", bank / "swap.tmp"
    os.replace(a, tmp)
    os.replace(b, a)
    os.replace(tmp, b)
    return "P09.kuzu"


def copied_from_other(bank: Path) -> str:
    shutil.copy(bank / "P37.kuzu", bank / "P09.kuzu")
    return "P09.kuzu"


def _manifest(bank: Path, change: Callable[[dict], None]) -> None:
    path = bank / "manifest.json"
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def manifest_counts(bank: Path) -> str:
    _manifest(bank, lambda d: d["participants"]["P09"]["counts"].__setitem__("segments", 161))
    return "P09.kuzu"


def manifest_hash(bank: Path) -> str:
    _manifest(bank, lambda d: d["participants"]["P09"]["integrity"].__setitem__("sha256", "0" * 64))
    return "P09.kuzu"


def manifest_entry_removed(bank: Path) -> str:
    _manifest(bank, lambda d: d["participants"].pop("P09"))
    return "P09.kuzu"


def manifest_damaged(bank: Path) -> str:
    path = bank / "manifest.json"
    path.write_text(path.read_text()[:-40])
    return "manifest.json"


def interrupted_write(bank: Path) -> str:
    _manifest(bank, lambda d: d.setdefault("writing", {}).__setitem__(
        "P09", {"op": "build", "pid": 2 ** 22 + 7, "since": "2025-01-01T00:00:00+00:00"}))
    return "P09.kuzu"


def not_recorded(bank: Path) -> str:
    """A bank made before integrity records (no hash in the manifest)."""
    _manifest(bank, lambda d: d["participants"]["P09"].pop("integrity"))
    return "P09.kuzu"


CORPUS: dict[str, Callable[[Path], str]] = {f.__name__: f for f in (
    truncate, zero_fill, damaged_pages, narration_edit, state_edit, edit_op_id, garbled_text_page, empty_file,
    missing_file, foreign_wal, shadow_file, swapped_files, copied_from_other, manifest_counts, manifest_hash,
    manifest_entry_removed, manifest_damaged, interrupted_write, not_recorded,
)}

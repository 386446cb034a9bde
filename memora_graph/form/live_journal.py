"""The journal of remembered moments: what a live writer changed, appended one line per moment,
so that the persisted tool stores (retrieve/persist.py) of the database as it was before stay
usable after it: a reader opens the stores and takes the journal's moments in (`MemoryView.absorb`,
the way a writable server's readers take each remember in), instead of computing and writing
every store again (15 s at 1,000 h).

`BANK/.cache/remembered-PXX.jsonl` holds one JSON line per committed moment (the `delta` a
remember hands its readers: the segment's row and vector, the entity rows written, the new
history entries, ...) and one `{"inferred": true}` line per background consolidation that
replaced the inferred records. Its record in the manifest (`derived.remembered`,
bank/derived.py) says which database it starts from (`from`: the sha256 the stores carry) and
which it leads to (`to`: the sha256 recorded when the writer closed cleanly), and the sha256
and length of its lines. A reader uses it only when both ends match: the stores' database at
`from`, the database as recorded now at `to`. Anything else (a writer killed before its close
recorded `to`, a write by other means, a journal edited) leaves the stores stale: written again,
as before the journal.

The writer continues the journal across sessions (`from` stays) while its `to` is the database
the writer opens, up to `MAX_MOMENTS` lines; past that, or where stores of the opened database
itself exist, it starts a new one (and the next reader writes the stores again once).
"""

from __future__ import annotations

import base64
import hashlib
import json
import logging
import os
from pathlib import Path

import numpy as np

from memora_graph.bank import Bank
from memora_graph.errors import BankError

RECORD = "remembered"  # its record in the manifest (bank/derived.py); it names no `files` (verify skips it)
TOOLS_RECORD = "tools"  # the persisted tool stores' record (retrieve/persist.py RECORD)
MAX_MOMENTS = 20_000  # past this many lines a writer starts a new journal (a reader's replay stays bounded)
FILENAME = "remembered-{participant}.jsonl"
_F32 = "$f32"

log = logging.getLogger("memora_graph.integrity")


def journal_path(bank_path: str | Path, participant: str) -> Path:
    return Path(bank_path) / ".cache" / FILENAME.format(participant=participant)


def _encode(value):
    """JSON-ready: vectors as base64 float32 (exact, a third of the text), tuples as lists."""
    if isinstance(value, np.ndarray):
        return {_F32: base64.b64encode(np.ascontiguousarray(value, dtype=np.float32).tobytes()).decode()}
    if isinstance(value, dict):
        return {k: (_vector(v) if k == "emb" and v is not None else _encode(v)) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_encode(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _vector(v):
    arr = np.asarray(v, dtype=np.float32)
    return {_F32: base64.b64encode(np.ascontiguousarray(arr).tobytes()).decode(), "list": not isinstance(v, np.ndarray)}


def _decode(value):
    if isinstance(value, dict):
        if _F32 in value:
            arr = np.frombuffer(base64.b64decode(value[_F32]), dtype=np.float32).copy()
            return [float(x) for x in arr] if value.get("list") else arr
        return {k: _decode(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_decode(v) for v in value]
    return value


def encode_line(delta: dict) -> bytes:
    return (json.dumps(_encode(delta), ensure_ascii=False, separators=(",", ":")) + "\n").encode()


def read(bank_path: str | Path, participant: str, record: dict) -> list[dict]:
    """The journal's lines as its record names them (its first `bytes` bytes, whose sha256 it
    recorded). Raises ValueError naming the file where they are not as recorded."""
    path = journal_path(bank_path, participant)
    size = record.get("bytes")
    if not isinstance(size, int) or size < 0:
        raise ValueError(f"{path}: its record has no length")
    with open(path, "rb") as fh:
        data = fh.read(size)
    if len(data) != size or hashlib.sha256(data).hexdigest() != record.get("sha256"):
        raise ValueError(f"{path}: not as recorded in the manifest (edited or truncated)")
    lines = [_decode(json.loads(line)) for line in data.splitlines() if line.strip()]
    if len(lines) != record.get("n"):
        raise ValueError(f"{path}: {len(lines)} lines where its record says {record.get('n')}")
    return lines


def usable(bank: Bank, participant: str, stores_of: str | None, db_sha256: str | None) -> dict | None:
    """The journal's record when it leads from the stores' database (`stores_of`) to the one
    recorded now (`db_sha256`), else None."""
    if not stores_of or not db_sha256:
        return None
    record = bank.derived.get(participant, RECORD)
    if isinstance(record, dict) and record.get("from") == stores_of and record.get("to") == db_sha256:
        return record
    return None


class Journal:
    """The writer's side: opened with the database's sha256 as the writer found it; `append` a
    committed moment's delta; `close` after the database's close recorded its new sha256."""

    def __init__(self, bank: Bank, participant: str, opened_sha256: str | None):
        self.bank, self.participant, self.path = bank, participant, journal_path(bank.path, participant)
        self.off = not opened_sha256  # --no-verify: nothing to tie the journal to
        self.broken = False
        self._fh = None
        if self.off:
            return
        record = bank.derived.get(participant, RECORD) or {}
        tools = bank.derived.get(participant, TOOLS_RECORD) or {}
        self.opened = opened_sha256
        self.start, self.n, self.size, self._hash = opened_sha256, 0, 0, hashlib.sha256()
        keep = (record.get("to") == opened_sha256 and tools.get("of") != opened_sha256
                and isinstance(record.get("n"), int) and record["n"] < MAX_MOMENTS and isinstance(record.get("bytes"), int))
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if keep:
                try:
                    with open(self.path, "rb") as fh:
                        data = fh.read(record["bytes"])
                except OSError:
                    data = b""
                if len(data) == record["bytes"] and hashlib.sha256(data).hexdigest() == record.get("sha256"):
                    self.start, self.n, self.size = record["from"], record["n"], len(data)
                    self._hash.update(data)
            self._fh = open(self.path, "r+b" if self.path.exists() else "w+b")
            self._fh.truncate(self.size)  # lines a killed session appended, or a journal started anew
            self._fh.seek(self.size)
            self._session = (self.n, self.size)  # where this session's lines begin
        except OSError as exc:
            self._fail(exc)

    def _fail(self, exc: Exception) -> None:
        log.warning(f"{self.path}: the journal of remembered moments could not be written ({exc}); "
                    "the tool stores are written again on the next open")
        self.broken = True

    def append(self, delta: dict) -> None:
        if self.off or self.broken:
            return
        try:
            line = encode_line(delta)
            self._fh.write(line)
        except (OSError, TypeError, ValueError) as exc:  # (a value JSON cannot carry: never half a line)
            self._fail(exc)
            return
        self._hash.update(line)
        self.n += 1
        self.size += len(line)

    def _rebase(self) -> None:
        """Keep this session's lines only: the journal then starts at the opened database."""
        n0, size0 = self._session
        try:
            with open(self.path, "rb") as fh:
                fh.seek(size0)
                data = fh.read(self.size - size0)
            tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
            with open(tmp, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
        except OSError as exc:
            self._fail(exc)
            return
        self.start, self.n, self.size, self._hash = self.opened, self.n - n0, len(data), hashlib.sha256(data)

    def note_inferred(self) -> None:
        """A consolidation replaced the inferred records (routines, preferences, links)."""
        self.append({"inferred": True})

    def close(self) -> None:
        """Record the journal as leading to the database as its close recorded it (call after
        the store's close); a broken journal is recorded as none."""
        if self.off:
            return
        try:
            if self._fh is not None:
                self._fh.flush()
                os.fsync(self._fh.fileno())
                self._fh.close()
        except OSError as exc:
            self._fail(exc)
        self._fh = None
        try:
            tools = self.bank.derived.get(self.participant, TOOLS_RECORD) or {}
            if not self.broken and self.start != self.opened and tools.get("of") == self.opened:
                self._rebase()  # stores of the opened database were written meanwhile (a server's open)
            if self.broken:
                self.bank.derived.drop(self.participant, RECORD)
                return
            entry = self.bank.manifest().get("participants", {}).get(self.participant, {})
            now = (entry.get("integrity") or {}).get("sha256")
            if not now:
                return
            self.bank.derived.put(self.participant, RECORD,
                                  {"from": self.start, "to": now, "n": self.n, "bytes": self.size,
                                   "sha256": self._hash.hexdigest()}, db_sha256=now)
        except (OSError, BankError) as exc:
            log.warning(f"{self.path}: not recorded in the manifest ({exc}); the tool stores are written again")

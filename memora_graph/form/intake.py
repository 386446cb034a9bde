"""The live writer's intake journal: every acknowledged moment's input, durable before its answer.

Kùzu's write-ahead log holds every commit since the last checkpoint, but a writer killed early in
a checkpoint can leave a log Kùzu 0.11.3 refuses to replay ("Found duplicated primary key value
..."), read-only and read-write alike; the database file then holds the last completed
checkpoint only. So the guarantee that no acknowledged moment is lost (docs/live-memory.md,
"Durability") does not rest on the log alone:

- before `remember` answers, the moment's input (its key and the moment or segment as given) is
  appended to `BANK/.live/intake-<participant>.jsonl`, flushed and fsync'd;
- after each completed checkpoint (and a clean close) the journal is emptied: it holds the moments
  since the last checkpoint, as the log does;
- a writer that finds a log it cannot replay, and a journal, moves the log aside into
  `BANK/.recovery/` (never deleted), opens the database as its last checkpoint left it, and
  re-applies the journal's moments in order, by key (a key already in the database is a duplicate:
  nothing is written). Every writer open re-applies what the journal holds that the database lacks.

Moments re-applied are perceived, embedded and edited again from the same input against the same
memory, in the same order, so their segments and turns are the ones first acknowledged.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
from pathlib import Path

from memora_graph.errors import BankError
from memora_graph.files import RECOVERY, side_files

FOLDER = ".live"  # BANK/.live/intake-<participant>.jsonl
log = logging.getLogger("memora_graph.integrity")


def journal_path(bank: Path, participant: str) -> Path:
    return Path(bank) / FOLDER / f"intake-{participant}.jsonl"


class Journal:
    """A participant's intake journal (see the module): `append` before an answer, `clear` after a
    checkpoint, `entries` to re-apply."""

    def __init__(self, bank: Path, participant: str):
        self.path = journal_path(bank, participant)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists()
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        if new:  # the file's name durable too: a journal that vanishes with a crash journals nothing
            _fsync_dir(self.path.parent)
        self.lines = 0  # appended since the last clear (by this writer)

    def append(self, key: str, entry: dict) -> None:
        """Append one acknowledged moment's input, durable (fsync'd) when this returns."""
        line = json.dumps({"key": key, **entry}, separators=(",", ":"), default=str) + "\n"
        os.write(self._fd, line.encode())
        os.fsync(self._fd)
        self.lines += 1

    def clear(self) -> None:
        """Empty the journal: what it held is in the database file (a checkpoint completed)."""
        if self._fd >= 0:
            os.ftruncate(self._fd, 0)
            os.fsync(self._fd)
            self.lines = 0

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


def entries(bank: Path, participant: str) -> list[dict]:
    """The journal's moments in order, one per key (the first); a torn last line (a kill while it
    was written: never acknowledged) is left out; a damaged line elsewhere is an error naming it."""
    path = journal_path(bank, participant)
    if not path.exists():
        return []
    lines = path.read_bytes().split(b"\n")
    out, seen = [], set()
    for i, raw in enumerate(lines, 1):
        if not raw.strip():
            continue
        try:
            entry = json.loads(raw)
            key = entry["key"]
        except (ValueError, KeyError, TypeError):
            if i == len(lines):  # the last line, without its newline: its append never returned
                break
            raise BankError(f"{path}, line {i}: not a journal entry (damaged); nothing was re-applied") from None
        if key not in seen:
            seen.add(key)
            out.append(entry)
    return out


def has_journal(bank: Path, participant: str) -> bool:
    return journal_path(bank, participant).exists()


def set_log_aside(db: Path) -> Path:
    """Move a database's write-ahead log (and shadow file) into BANK/.recovery/ (never deleted), so
    the database opens as its last completed checkpoint left it. Returns the folder."""
    db = Path(db)
    dest = db.parent / RECOVERY / f"{db.name}-unreplayable-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}-{os.getpid()}"
    dest.mkdir(parents=True, exist_ok=True)
    for side in side_files(db):
        shutil.move(str(side), dest / side.name)
    _fsync_dir(db.parent)
    return dest


def recover_without_log(bank: Path, participant: str, db: Path, why: Exception) -> Path | None:
    """After the log of a killed live writer could not be replayed (`why`): with a journal, set
    the log aside (the journal re-applies what it held when the writer opens) and return where it
    went; without one (a writer from before journals), None: the caller raises `why`."""
    if not has_journal(bank, participant):
        return None
    dest = set_log_aside(db)
    n = len(entries(bank, participant))
    log.warning(f"{db}: its write-ahead log cannot be replayed ({why}); moved to {dest}. The database opens as its "
                f"last checkpoint left it, and the intake journal re-applies the {n} moment(s) acknowledged since")
    return dest


def reapply(writer) -> int:
    """Re-apply the journal's moments the writer's database lacks (by key), in order; then
    checkpoint, which empties the journal. Returns how many were written."""
    from memora_graph.form.live import Moment

    done = 0
    for entry in entries(writer.bank.path, writer.participant):
        key = entry["key"]
        if key in writer._keys:
            continue
        if "segment" in entry:
            writer.remember_segment(entry["segment"], key=key)
        else:
            m = entry["moment"]
            writer.remember(Moment(m["video"], m["start"], m["end"], m["text"], key))
        done += 1
    if done:
        log.warning(f"{writer.store.path}: re-applied {done} acknowledged moment(s) from the intake journal")
        writer.checkpoint()
    return done


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)

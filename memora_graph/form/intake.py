"""The live writer's intake journal: every acknowledged moment's input, durable before its answer.

Kùzu's write-ahead log holds every commit since the last checkpoint, but a writer killed early in
a checkpoint can leave a log Kùzu 0.11.3 refuses to replay ("Found duplicated primary key value
..."), read-only and read-write alike; the database file then holds the last completed
checkpoint only. So the guarantee that no acknowledged moment is lost (docs/live-memory.md,
"Durability") does not rest on the log alone:

- before the moment's transaction (so before `remember` answers), its input (its key and the
  moment or segment as given) is appended to `BANK/.live/intake-<participant>.jsonl` and
  fdatasync'd; a transaction that fails appends a cancel line for the key;
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

from memora_graph.errors import BankError, MemoraError
from memora_graph.files import RECOVERY, side_files
from memora_graph.store import rebuild_from_rows

FOLDER = ".live"  # BANK/.live/intake-<participant>.jsonl
log = logging.getLogger("memora_graph.integrity")


def journal_path(bank: Path, participant: str) -> Path:
    return Path(bank) / FOLDER / f"intake-{participant}.jsonl"


class Journal:
    """A participant's intake journal (see the module). A remember calls `append` before its
    transaction (the line is durable when it returns) and `cancel` if the transaction failed;
    `clear` after a checkpoint; `entries` reads it back. (Its fsync in a thread overlapping the
    commit made remember slower, not faster: p50 ~20 ms against ~13 inline on a 10 h bank; see
    docs/findings/live-intake-journal.md.)"""

    def __init__(self, bank: Path, participant: str):
        self.path = journal_path(bank, participant)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists()
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        if new:  # the file's name durable too: a journal that vanishes with a crash journals nothing
            _fsync_dir(self.path.parent)
        self.lines = 0  # appended since the last clear (by this writer)

    def append(self, key: str, entry: dict) -> None:
        """Append one moment's input, durable (fdatasync'd: the data and the file's new size) when
        this returns; if it cannot be made durable, a cancel line follows it (best effort) and the
        error is raised."""
        self._write({"key": key, **entry})
        try:
            os.fdatasync(self._fd)
        except OSError:
            try:
                self._write({"key": key, "cancel": True})
            except OSError:
                pass
            raise
        self.lines += 1

    def cancel(self, key: str) -> None:
        """The moment's transaction failed (nothing of it was kept): its line no longer counts."""
        try:
            self._write({"key": key, "cancel": True})
            os.fdatasync(self._fd)
        except OSError as exc:  # the failure the caller raises matters more; re-applying tolerates the line
            log.warning(f"{self.path}: could not cancel {key!r} ({exc}); re-applying it may write it later")

    def _write(self, entry: dict) -> None:
        os.write(self._fd, (json.dumps(entry, separators=(",", ":"), default=str) + "\n").encode())

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
    """The journal's moments in order, one per key (the first not cancelled: a moment whose
    transaction failed is followed by a cancel line); a torn last line (a kill while it was
    written: never acknowledged) is left out; a damaged line elsewhere is an error naming it."""
    path = journal_path(bank, participant)
    if not path.exists():
        return []
    lines = path.read_bytes().split(b"\n")
    out: dict[str, dict] = {}
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
        if entry.get("cancel"):
            out.pop(key, None)
        elif key not in out:
            out[key] = entry
    return list(out.values())


def has_journal(bank: Path, participant: str) -> bool:
    return journal_path(bank, participant).exists()


def set_log_aside(db: Path) -> Path:
    """Move a database's write-ahead log (and shadow file) into BANK/.recovery/ (never deleted), so
    the database opens as its last completed checkpoint left it, and write the database again from
    its rows (`store.rebuild_from_rows`; the file as it was goes into the same folder): a writer
    killed inside a checkpoint can leave a file whose primary-key index no longer matches its rows,
    which refuses the journal's moments as duplicates. Returns the folder."""
    db = Path(db)
    # (not named like keep_log's copies, which it prunes to the newest few)
    dest = db.parent / RECOVERY / f"unreplayable-{db.name}-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}-{os.getpid()}"
    dest.mkdir(parents=True, exist_ok=True)
    for side in side_files(db):
        shutil.move(str(side), dest / side.name)
    _fsync_dir(db.parent)
    t0 = time.perf_counter()
    try:
        rebuild_from_rows(db, dest)
    except (MemoraError, OSError) as exc:  # the file as it was still opens: the journal re-applies against it
        log.warning(f"{db}: could not write it again from its rows ({exc}); re-applying against the file as it is")
    else:
        log.warning(f"{db}: written again from its rows in {time.perf_counter() - t0:.1f} s (the file as it was is "
                    f"in {dest})")
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


def reapply(writer, moment) -> int:
    """Re-apply the journal's moments the writer's database lacks (by key), in order; then
    checkpoint, which empties the journal. Returns how many were written. `moment`: the class
    a moment is given to `writer.remember` as (form/live.py's `Moment`; passed in, so this
    module does not import the writer's)."""
    todo = [e for e in entries(writer.bank.path, writer.participant) if e["key"] not in writer._keys]
    if not todo:
        return 0
    hook, writer._on_commit = writer._on_commit, None  # (as the writer opens: its readers are not yet there)
    try:
        done = _reapply(writer, todo, moment)
    finally:
        writer._on_commit = hook
    if done:
        log.warning(f"{writer.store.path}: re-applied {done} acknowledged moment(s) from the intake journal")
        writer.checkpoint()
    return done


def _reapply(writer, todo: list[dict], moment) -> int:
    done = 0
    for entry in todo:
        key = entry["key"]
        if key in writer._keys:
            continue
        try:
            if "segment" in entry:
                writer.remember_segment(entry["segment"], key=key)
            else:
                m = entry["moment"]
                writer.remember(moment(m["video"], m["start"], m["end"], m["text"], key))
        except MemoraError as exc:  # a moment whose writer died in its transaction (never acknowledged), or
            log.warning(f"{journal_path(writer.bank.path, writer.participant)}: {key!r} could not be re-applied "
                        f"({exc}); left out")  # one failing again: the rest go on
            continue
        done += 1
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

"""A memory bank: a directory with one Kùzu database per participant and a manifest.

Memory is personal: one file per person means a build of one participant never locks
another's memory, and forgetting a person (`Bank.forget`) removes every trace of them. The
manifest records what each write left behind: videos, record counts, and (`integrity`) the
sha256, size and rows per table of the database file after it was closed. Every open checks the
file against that record before Kùzu reads a byte of it (Kùzu 0.11.3 has no page checksums: a
damaged file can return wrong values or crash the process), and refuses a database whose last
write did not finish, a write-ahead log that does not belong to it, or a file the manifest does
not list. `memora verify BANK` gives the full report; `--no-verify` bypasses the checks.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

from typing import TYPE_CHECKING

from memora_graph.errors import BankError
from memora_graph.files import file_kind, file_sha256, side_files

if TYPE_CHECKING:  # imported where used: a one-shot command that reads persisted stores never loads Kùzu
    import polars as pl

    from memora_graph.store import Store

MANIFEST = "manifest.json"
FORMAT = 1
BUILD_LOCK = ".build.lock"
VERIFIED = ".verified.json"
NO_VERIFY_ENV = "MEMORA_NO_VERIFY"  # set by `--no-verify`; inherited by worker processes
_PID = re.compile(r"\AP\d{2}\Z")  # \Z: "$" would also accept "P09\n"
_DB = re.compile(r"\A(P\d{2})\.kuzu\Z")
CHECKED_COUNTS = ("segments", "entity_records", "state_events", "places")
log = logging.getLogger("memora_graph.integrity")
_NOTICED: set[tuple[str, str]] = set()
_LOCK_FDS: dict[str, int] = {}


def verify_default() -> bool:
    return os.environ.get(NO_VERIFY_ENV, "") in ("", "0")


def is_participant_id(name: str) -> bool:
    """Whether `name` is a participant id (P01 ... P99)."""
    return bool(_PID.match(name))


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def pid_alive(pid) -> bool:
    """Whether a process with this id runs on this machine (False for None or garbage)."""
    try:
        os.kill(int(pid), 0)
    except (OSError, ValueError, TypeError):
        return False
    return True


def _shown(value: object) -> str:
    text = json.dumps(value) if isinstance(value, (str, int, float, list, dict, type(None))) else repr(value)
    return f"a JSON {type(value).__name__} {text[:60]}"


class Bank:
    def __init__(self, path: str | Path):
        self.path = Path(path)

    # -- manifest ----------------------------------------------------------------------
    @property
    def manifest_path(self) -> Path:
        return self.path / MANIFEST

    def exists(self) -> bool:
        return self.manifest_path.exists()

    def manifest(self) -> dict:
        if not self.exists():
            if self.path.is_dir() and any(self.path.glob("*.kuzu")):
                raise BankError(f"{self.path}: has databases but no {MANIFEST}; not a complete memora bank")
            raise BankError(f"{self.path}: no memory bank here (no {MANIFEST}). Build one with `memora build {self.path}`.")
        try:
            data = json.loads(self.manifest_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
            raise BankError(f"{self.manifest_path}: damaged manifest ({type(exc).__name__}: {exc})") from exc
        except OSError as exc:
            raise BankError(f"{self.manifest_path}: cannot be read ({exc.strerror or exc})") from exc
        if not isinstance(data, dict):
            raise BankError(f"{self.manifest_path}: damaged manifest (a JSON {type(data).__name__}, not an object)")
        if data.get("format") != FORMAT:
            raise BankError(f"{self.manifest_path}: unknown bank format {data.get('format')!r}")
        parts = data.get("participants")
        if not isinstance(parts, dict) or not all(isinstance(k, str) and _PID.match(k) and isinstance(v, dict)
                                                  and isinstance(v.get("counts", {}), dict) for k, v in parts.items()):
            raise BankError(f"{self.manifest_path}: damaged manifest ('participants' is not a map of participant ids "
                            "to their records)")
        writing = data.get("writing", {})
        if not isinstance(writing, dict) or not all(isinstance(k, str) and _PID.match(k) and isinstance(v, dict)
                                                    for k, v in writing.items()):
            raise BankError(f"{self.manifest_path}: damaged manifest (field 'writing' is not a map of participant ids "
                            f"to write marks, but {_shown(writing)})")
        for p, entry in parts.items():
            for key in ("counts", "integrity"):
                if entry.get(key) is not None and not isinstance(entry[key], dict):
                    raise BankError(f"{self.manifest_path}: damaged manifest (participants.{p}.{key} is "
                                    f"{_shown(entry[key])}, not a map)")
        return data

    def init(self, mode: str, embed_model: str, consolidated: bool) -> dict:
        if self.exists():
            data = self.manifest()
            if data["mode"] != mode:
                raise BankError(f"{self.path}: is a '{data['mode']}' bank; cannot add a '{mode}' build to it. Use another directory.")
            if data["embed_model"] != embed_model:
                raise BankError(f"{self.path}: embeddings are from {data['embed_model']}, not {embed_model}. Use another directory.")
            return data
        self.path.mkdir(parents=True, exist_ok=True)
        (self.path / BUILD_LOCK).touch()
        data = {"format": FORMAT, "mode": mode, "embed_model": embed_model, "consolidated": consolidated, "participants": {}}
        self.write_manifest(data)
        return data

    @contextmanager
    def manifest_lock(self) -> Iterator[None]:
        """Exclusive access to the manifest for a read-modify-write, across processes: the
        participants of a bank are built side by side by worker processes (`memora build --jobs`)."""
        self.path.mkdir(parents=True, exist_ok=True)
        try:
            import fcntl
        except ImportError:  # not POSIX: builds there run one participant at a time
            yield
            return
        with open(self.path / ".manifest.lock", "a") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def write_manifest(self, data: dict) -> None:
        tmp = self.manifest_path.with_suffix(".json.tmp")
        try:
            tmp.write_text(json.dumps(data, indent=2, sort_keys=True))
        except OSError:
            tmp.unlink(missing_ok=True)
            raise
        os.replace(tmp, self.manifest_path)  # atomic: never a half-written manifest

    def update_manifest(self, change: Callable[[dict], None]) -> dict:
        """Read, change and write the manifest under its lock."""
        with self.manifest_lock():
            data = self.manifest()
            before = json.dumps(data, sort_keys=True)
            change(data)
            if json.dumps(data, sort_keys=True) != before:  # an unchanged manifest is not rewritten
                self.write_manifest(data)
        return data

    def record_participant(self, participant: str, videos: list[str], counts: dict,
                           annotations: dict[str, str] | None = None, extra: dict | None = None) -> None:
        """Record what a build wrote. `annotations`: per video, the fingerprint of the rows it was
        built from (a later build tells when they changed). `extra` sets entry fields a build
        leaves to later steps (`consolidated`, `inferred`, `indexes`): an import brings them along."""
        def change(data: dict) -> None:
            entry = {"db": f"{participant}.kuzu", "videos": sorted(videos), "counts": dict(counts)}
            old = data["participants"].get(participant, {})
            # the database keeps its indexes and its inferred knowledge (until consolidation runs again)
            entry.update({k: old[k] for k in ("indexes", "consolidated", "inferred", "integrity") if k in old})
            for k in ("routines", "preferences"):
                if k in old.get("counts", {}) and k not in counts:
                    entry["counts"][k] = old["counts"][k]
            fingerprints = {**old.get("annotations", {}), **(annotations or {})}
            if fingerprints:
                entry["annotations"] = {v: fingerprints[v] for v in sorted(fingerprints) if v in entry["videos"]}
            extra_fields = dict(extra or {})
            indexes = extra_fields.pop("indexes", None)
            entry.update(extra_fields)
            data["participants"][participant] = entry
            if indexes is not None:
                self.set_indexes(data, participant, indexes)
            if "consolidated" in extra_fields:
                self.set_condition(data)

        self.update_manifest(change)

    # -- integrity -----------------------------------------------------------------------
    def mark_writing(self, participant: str, op: str) -> None:
        """Say in the manifest that this process is about to write a participant's database.
        Until `record_integrity` clears it, readers refuse the participant: if the process dies,
        the mark says which write did not finish."""
        mark = {"op": op, "pid": os.getpid(), "since": _now()}
        self.update_manifest(lambda data: data.setdefault("writing", {}).__setitem__(participant, mark))

    def abandon_writing(self, participant: str) -> None:
        """After this process's write of a participant failed: keep the mark (the write did not
        finish) but no longer as this process's own, so that later opens here check the
        participant like any reader does."""
        def change(data: dict) -> None:
            mark = data.get("writing", {}).get(participant)
            if mark and mark.get("pid") == os.getpid():
                mark["pid"] = None
                mark["failed_in"] = os.getpid()

        if self.exists():
            try:
                self.update_manifest(change)
            except OSError:  # e.g. a full disk: the mark stays this process's, and reads as unfinished once it exits
                pass

    def clear_writing(self, participant: str) -> None:
        def change(data: dict) -> None:
            marks = data.get("writing", {})
            if marks.get(participant, {}).get("pid") == os.getpid():
                del marks[participant]
            if not marks:
                data.pop("writing", None)

        self.update_manifest(change)

    def record_integrity(self, participant: str) -> dict:
        """(Re)record a participant's integrity after any write: the sha256 and size of its
        database file and its rows per table (with the store counts), and clear the write mark.
        Call it once the database is closed (a clean close leaves no log or shadow file). Returns
        the integrity record. `Bank.open(..., read_only=False)` calls it when the store closes."""
        from memora_graph.store import Store

        db = self.db_path(participant)
        sides = side_files(db)
        if sides:
            raise BankError(f"{', '.join(map(str, sides))}: still next to {db.name}; close every writer before "
                            "recording its integrity")
        with Store(db, read_only=True) as store:
            tables = store.table_counts(participant)
            counts = {k: int(v or 0) for k, v in store.rows("store_counts", participant=participant)[0].items()}
        st = db.stat()
        record = {"sha256": file_sha256(db, st), "bytes": st.st_size, "recorded_at": _now(),
                  "tables": {t: v["rows"] for t, v in tables.items()},
                  "other_participant_rows": sum(v["other_participant"] for v in tables.values())}

        def change(data: dict) -> None:
            entry = data["participants"].get(participant)
            if entry is None:
                raise BankError(f"{self.manifest_path}: no entry for {participant} to record its integrity in")
            entry["counts"] = {**entry.get("counts", {}), **counts}
            entry["integrity"] = record
            marks = data.get("writing", {})
            marks.pop(participant, None)
            if not marks:
                data.pop("writing", None)

        self.update_manifest(change)
        self._remember(participant, st, record["sha256"])
        return record

    def check(self, participant: str, data: dict | None = None) -> None:
        """Refuse, before Kùzu touches it, a participant database whose write did not finish,
        that has a write-ahead log or shadow file it did not leave, or whose size or sha256
        differs from the manifest's record. The messages name the file and what to do."""
        data = data or self.manifest()
        db = self.db_path(participant)
        mark = data.get("writing", {}).get(participant)
        if mark:
            if mark.get("pid") == os.getpid():
                return  # this process is writing it (a build's consolidation step)
            raise BankError(self.interrupted_message(participant, mark))
        entry = data["participants"].get(participant)
        if entry is None:
            raise BankError(self._not_listed(participant, data))
        integ = entry.get("integrity")
        if not integ:
            raise BankError(f"{db}: {MANIFEST} records no hash for it (a bank built before integrity records?). "
                            f"`memora verify {self.path}` checks it; `memora verify {self.path} --accept {participant}` "
                            f"records it as it is now; or rebuild: `memora build {self.path} --rebuild {participant}`.")
        self.checked_db_file(participant)
        sides = side_files(db)
        if sides:
            raise BankError(f"{sides[0]}: a {'write-ahead log' if sides[0].suffix == '.wal' else 'shadow file'} next "
                            f"to {db.name}, which was closed cleanly when its hash was recorded: it does not belong "
                            f"to this database (copied from elsewhere, or left by a write outside memora). It was not "
                            f"replayed. Move it away and retry; `memora verify {self.path}` reports every file.")
        st = db.stat()
        digest = None
        if st.st_size == integ.get("bytes"):
            if self._seen_unchanged(participant, st, integ.get("sha256")):
                return
            digest = file_sha256(db, st)
            if digest == integ.get("sha256"):
                self._remember(participant, st, digest)
                return
        owner = self._recorded_for(data, participant, st.st_size, db, st, digest)
        if owner:
            raise BankError(f"{db}: holds the database recorded for {owner} in {MANIFEST}, not {participant}'s "
                            "(files swapped or copied between participants?). Nothing was read from it.")
        what = (f"is {st.st_size} bytes, but {integ.get('bytes')} were recorded in {MANIFEST} (truncated or replaced)"
                if digest is None else f"its content does not match the sha256 recorded in {MANIFEST} (damaged, "
                                       "or edited outside memora)")
        raise BankError(f"{db}: {what}. Nothing was read from it. `memora verify {self.path}` reports every "
                        f"participant; rebuild this one with `memora build {self.path} --rebuild {participant}`.")

    def check_before_build(self, participant: str) -> None:
        """Before a build reads (and later extends) a participant's database: a sealed one must
        match its record; an interrupted build's one, with a write-ahead log or shadow file to
        replay, is opened in a child process first (a crash there is an error here); a database
        the manifest does not list is refused. Skipped under `--no-verify`."""
        if not verify_default() or not self.exists():
            return
        data = self.manifest()
        db = self.db_path(participant)
        mark = data.get("writing", {}).get(participant)
        if mark:
            if mark.get("pid") != os.getpid() and pid_alive(mark.get("pid")):
                raise BankError(self.interrupted_message(participant, mark))
            if side_files(db):
                from memora_graph.files import probe

                probe(db, participant)
            return
        entry = data["participants"].get(participant)
        if entry is None:
            if db.exists():
                raise BankError(self._not_listed(participant, data))
            return
        if entry.get("integrity"):
            self.check(participant, data)

    # A file's (device, inode, size, mtime, ctime) after it last hashed to its recorded sha256, in
    # BANK/.verified.json, so that a reader need not hash an unchanged file again. Any write to
    # the file, copy or swap changes ctime or the inode (ctime cannot be set back without root
    # changing the clock), so changed bytes are always hashed; damage beneath the filesystem (bit
    # rot) is what only `memora verify`, which always hashes, can see.
    @staticmethod
    def _stat_key(st) -> list[int]:
        return [st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]

    def _seen(self) -> dict:
        try:
            data = json.loads((self.path / VERIFIED).read_text())
            return data if isinstance(data, dict) else {}
        except (OSError, ValueError):
            return {}

    def _seen_unchanged(self, participant: str, st, sha256: str | None) -> bool:
        seen = self._seen().get(participant) or {}
        return bool(sha256) and seen.get("sha256") == sha256 and seen.get("stat") == self._stat_key(st)

    def _remember(self, participant: str, st, sha256: str) -> None:
        seen = self._seen()
        seen[participant] = {"sha256": sha256, "stat": self._stat_key(st)}
        tmp = self.path / f"{VERIFIED}.{os.getpid()}.tmp"
        try:
            tmp.write_text(json.dumps(seen, sort_keys=True))
            os.replace(tmp, self.path / VERIFIED)
        except OSError:  # a read-only bank: hash again next time
            tmp.unlink(missing_ok=True)

    def forget_seen(self, participant: str) -> None:
        seen = self._seen()
        if seen.pop(participant, None) is not None:
            tmp = self.path / f"{VERIFIED}.{os.getpid()}.tmp"
            tmp.write_text(json.dumps(seen, sort_keys=True))
            os.replace(tmp, self.path / VERIFIED)

    def _recorded_for(self, data: dict, participant: str, size: int, db: Path, st, digest: str | None) -> str | None:
        for other, entry in sorted(data["participants"].items()):
            integ = entry.get("integrity") or {}
            if other != participant and integ.get("bytes") == size:
                if (digest or file_sha256(db, st)) == integ.get("sha256"):
                    return other
        return None

    def interrupted_message(self, participant: str, mark: dict) -> str:
        db, op, pid, since = self.db_path(participant), mark.get("op", "write"), mark.get("pid"), mark.get("since", "?")
        pid = pid if pid is not None else mark.get("failed_in")
        if mark.get("pid") is not None and pid_alive(pid):
            return (f"{db}: being written by process {pid} ({op} since {since}); wait for it to finish "
                    "(or stop it), then retry.")
        if op == "build":
            return (f"{db}: its build was interrupted ({since}, process {pid} failed or is gone), so {participant}'s memory is "
                    f"incomplete. Resume it with `memora build {self.path} --participants {participant}` (or "
                    f"`memora build {self.path} --rebuild {participant}`).")
        if op == "live":
            return (f"{db}: its live writer ({since}, process {pid}) stopped without closing; what it acknowledged is in "
                    f"its write-ahead log. The next writer replays it (`memora remember {self.path} --participant "
                    f"{participant} ...`, `memora serve {self.path} --participant {participant} --writable`), as does "
                    f"`memora verify {self.path} --accept {participant}`.")
        return (f"{db}: a write to it ({op}, {since}) did not finish (process {pid} failed or is gone). `memora verify {self.path}` "
                f"reports it; `memora verify {self.path} --accept {participant}` keeps what that write committed, "
                f"or rebuild: `memora build {self.path} --rebuild {participant}`.")

    def _not_listed(self, participant: str, data: dict) -> str:
        known = ", ".join(sorted(data["participants"])) or "none"
        db = self.db_path(participant)
        if db.exists():
            return (f"{db}: exists, but {MANIFEST} does not list {participant} (its entry was removed, or the file was "
                    f"copied in), so it is not read. `memora verify {self.path}` reports it; `memora forget "
                    f"{self.path} --participant {participant}` deletes it. (The bank has: {known})")
        return f"{self.path}: participant {participant} is not in this bank (has: {known})"

    def notices(self, data: dict | None = None) -> list[tuple[str, str]]:
        """What a reader should know about the whole bank, as (participant, text), from a
        directory listing (no hashing): interrupted or running writes, staged videos of
        interrupted builds, databases the manifest does not list, listed participants whose
        database is missing."""
        data = data or self.manifest()
        out = []
        marks = data.get("writing", {})
        for p, mark in sorted(marks.items()):
            if mark.get("pid") != os.getpid():
                out.append((p, self.interrupted_message(p, mark)))
        staging = self.path / ".staging"
        if staging.is_dir():
            for d in sorted(x for x in staging.iterdir() if x.is_dir() and _PID.match(x.name)):
                n = sum(1 for x in d.iterdir() if x.is_dir() and not x.name.startswith("."))
                if n and d.name not in marks:
                    out.append((d.name, f"{d}: a build of {d.name} was interrupted with {n} video(s) staged; "
                                        f"`memora build {self.path} --participants {d.name}` resumes it"))
        for f in sorted(self.path.glob("P*.kuzu")):
            m = _DB.match(f.name)
            if m and m.group(1) not in data["participants"] and m.group(1) not in marks:
                out.append((m.group(1), self._not_listed(m.group(1), data)))
        for p in sorted(data["participants"]):
            if p not in marks and not self.db_path(p).exists():
                out.append((p, f"{self.db_path(p)}: missing, but {MANIFEST} lists {p}"))
        return out

    def _notify(self, data: dict, skip: str | None = None) -> None:
        """Log the bank's notices once per process (the CLI prints them as warnings), except
        those about `skip`, the participant being opened (its own check says it)."""
        for p, line in self.notices(data):
            key = (str(self.path.resolve()), line)
            if p != skip and key not in _NOTICED:
                _NOTICED.add(key)
                log.warning(line)

    @contextmanager
    def participant_lock(self, participant: str, wait_s: float = 10.0) -> Iterator[None]:
        """Exclusive, across processes, for building or forgetting one participant: a byte-range
        lock on BANK/.build.lock (one byte per participant number), held for the whole build.
        Waits up to `wait_s` (the worker of a build that was just killed dies a moment after it)."""
        self.db_path(participant)
        try:
            import fcntl
        except ImportError:
            yield
            return
        path = self.path / BUILD_LOCK
        self.path.mkdir(parents=True, exist_ok=True)
        key = str(path.resolve())
        if key not in _LOCK_FDS:  # POSIX record locks belong to the process: keep one descriptor open
            _LOCK_FDS[key] = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        fd, n = _LOCK_FDS[key], int(participant[1:])
        deadline = time.monotonic() + wait_s
        while True:
            try:
                fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB, 1, n)
                break
            except OSError:
                if time.monotonic() >= deadline:
                    raise BankError(f"{self.path}: {participant} is being built (or forgotten) by another process; "
                                    "wait for it to finish, then retry") from None
                time.sleep(0.1)
        try:
            yield
        finally:
            fcntl.lockf(fd, fcntl.LOCK_UN, 1, n)

    @staticmethod
    def set_condition(data: dict) -> None:
        """The bank-level condition in a manifest `data`, from its participants' `consolidated`:
        memora_full when all are, memora_episodic when none is, else mixed."""
        flags = [e.get("consolidated", False) for e in data["participants"].values()]
        data["consolidated"] = bool(flags) and all(flags)
        data["condition"] = "memora_full" if data["consolidated"] else ("memora_episodic" if not any(flags) else "mixed")

    # -- optional indexes ----------------------------------------------------------------
    @staticmethod
    def set_indexes(data: dict, participant: str, names: list[str]) -> None:
        """Record in a manifest `data` the indexes a participant's database has, and per kind
        whether every participant has all of them (`data["indexes"]`, e.g. {"fts": false})."""
        from memora_graph.store import INDEX_KINDS, index_names

        entry = data["participants"].get(participant)
        if entry is not None:
            entry["indexes"] = sorted(names)
        parts = data["participants"].values()
        data["indexes"] = {kind: bool(parts) and all(set(index_names(kind)) <= set(e.get("indexes", [])) for e in parts)
                           for kind in INDEX_KINDS}

    def build_indexes(self, participants: list[str] | None = None, fts: bool = False, hnsw: bool = False,
                      on_participant: Callable[[str, dict], None] | None = None) -> dict[str, dict]:
        """Add the optional indexes to existing databases (a build makes none unless asked): `fts`
        for the 'fts' / 'kuzu' / 'hnsw' retrieval recipes, `hnsw` for the 'hnsw' recipe. An index a
        database already has is kept (never dropped and re-created). Returns, per participant, the
        indexes created now, those it has, and the seconds spent."""
        if not (fts or hnsw):
            raise BankError("nothing to build: ask for the full-text (fts) and/or the HNSW (hnsw) indexes")
        known = self.participants()
        pids = participants or known
        missing = sorted(set(pids) - set(known))
        if missing:
            raise BankError(f"{self.path}: participant(s) {', '.join(missing)} not in this bank (has: {', '.join(known) or 'none'})")
        out = {}
        for p in pids:
            t0 = time.perf_counter()
            store = self.open(p, read_only=False)
            try:
                created = store.ensure_indexes(fts=fts, hnsw=hnsw)
                have = sorted(store.indexes())
            finally:
                store.close()  # records the database's integrity again
            self.update_manifest(lambda data, p=p, have=have: self.set_indexes(data, p, have))
            out[p] = {"created": created, "indexes": have, "seconds": time.perf_counter() - t0}
            if on_participant:
                on_participant(p, out[p])
        return out

    # -- participants ------------------------------------------------------------------
    def participants(self) -> list[str]:
        data = self.manifest()
        self._notify(data)
        return sorted(data["participants"])

    def db_path(self, participant: str) -> Path:
        if not isinstance(participant, str) or not _PID.match(participant):
            raise BankError(f"participant must look like P01, not {participant!r}")
        return self.path / f"{participant}.kuzu"

    def checked_db_file(self, participant: str) -> Path:
        """A participant's database path, refused (BankError naming it) unless it is a regular
        file of its own, directly inside the bank: not missing, not a folder, a device, a pipe or
        a symbolic link (which could point at a copy outside the bank, or /dev/zero)."""
        db = self.db_path(participant)
        try:
            st = db.lstat()
        except FileNotFoundError:
            raise BankError(f"{db}: missing. Rebuild it with `memora build {self.path} --rebuild {participant}`, or "
                            f"`memora forget {self.path} --participant {participant}`.") from None
        except OSError as exc:
            raise BankError(f"{db}: cannot be read ({exc.strerror or exc})") from None
        kind = file_kind(st)
        if kind != "file":
            raise BankError(f"{db}: is {kind}, not a database file; nothing was read from it. Move it away and "
                            f"rebuild: `memora build {self.path} --rebuild {participant}`.")
        if db.resolve().parent != self.path.resolve():
            raise BankError(f"{db}: resolves to {db.resolve()}, outside the bank {self.path.resolve()}; refused")
        return db

    def open(self, participant: str, read_only: bool = True, check: bool = True, *, verify: bool | None = None,
             op: str = "write") -> Store:
        """Open a participant's database after checking it (`check`): against its integrity
        record before Kùzu opens it, then its record counts against the manifest. `verify=False`
        (`--no-verify`; default: on unless MEMORA_NO_VERIFY is set) skips every check knowingly.
        A read-write store records the database's integrity again when it closes; until then the
        manifest's write mark names `op` (a live writer's is "live")."""
        from memora_graph.store import Store

        data = self.manifest()
        verify = verify_default() if verify is None else verify
        if participant not in data["participants"] and not (not verify and self.db_path(participant).exists()):
            raise BankError(self._not_listed(participant, data))
        ours = self.writing_here(participant, data)  # a build of this process: its content is in flux
        if not ours:
            self._notify(data, skip=participant if verify else None)
        checked = check and verify and not ours
        if self.db_path(participant).exists() or self.db_path(participant).is_symlink():
            self.checked_db_file(participant)  # a folder, device or link is refused even under --no-verify
        if checked:
            self.check(participant, data)
            if not read_only:  # the counts, before a write changes the file
                with Store(self.db_path(participant), read_only=True) as store:
                    self.verify_counts(participant, store, data["participants"][participant].get("counts", {}))
        if not read_only and not ours:
            self.mark_writing(participant, op)
        try:
            store = Store(self.db_path(participant), read_only=read_only,
                          on_close=None if read_only or ours else (lambda s: self.record_integrity(participant)),
                          on_fail=None if read_only or ours else (lambda s: self.abandon_writing(participant)))
        except BaseException:
            if not read_only and not ours:
                self.clear_writing(participant)
            raise
        if checked and read_only:
            try:
                self.verify_counts(participant, store, data["participants"][participant].get("counts", {}))
            except BaseException:
                store.close()
                raise
        return store

    def checked_sha256(self, participant: str) -> str | None:
        """Run the checks a read-only `open` runs before Kùzu touches the file (listed, no write
        in progress, no foreign log, size and sha256 as recorded) without opening it, and return
        the recorded sha256 the file matches: what files derived from the database are tied to.
        None under --no-verify or while this process writes it (nothing to vouch for then)."""
        data = self.manifest()
        if not verify_default() or self.writing_here(participant, data):
            return None
        if participant not in data["participants"]:
            raise BankError(self._not_listed(participant, data))
        self._notify(data, skip=participant)
        self.check(participant, data)
        return data["participants"][participant]["integrity"]["sha256"]

    def writing_here(self, participant: str, data: dict | None = None) -> bool:
        """Whether this process holds the participant's write mark (it is building it)."""
        data = data or self.manifest()
        return data.get("writing", {}).get(participant, {}).get("pid") == os.getpid()

    def verify_counts(self, participant: str, store: Store, expected: dict) -> None:
        try:
            got = {k: int(v or 0) for k, v in store.run("store_counts", participant=participant).to_dicts()[0].items()}
        except Exception as exc:
            raise BankError(f"{self.db_path(participant)}: cannot read the database ({exc}); it is damaged. Rebuild it "
                            f"with `memora build {self.path} --rebuild {participant}`.") from exc
        diff = {k: (expected.get(k), got.get(k)) for k in CHECKED_COUNTS if expected.get(k) != got.get(k)}
        if diff:
            detail = ", ".join(f"{k} manifest={a} database={b}" for k, (a, b) in diff.items())
            raise BankError(
                f"{self.db_path(participant)}: does not match {MANIFEST} ({detail}). The manifest was edited, or the "
                f"database damaged; `memora verify {self.path}` reports it, `memora build {self.path} --rebuild "
                f"{participant}` rebuilds it."
            )

    def run_each(self, name: str, participants: list[str] | None = None, **params) -> pl.DataFrame:
        """Run a named query over each participant's database and concatenate the frames."""
        import polars as pl

        frames = []
        for p in participants or self.participants():
            with self.open(p) as store:
                df = store.run(name, participant=p, **params)
            frames.append(df.with_columns(pl.lit(p).alias("participant")).select(["participant", *df.columns]) if "participant" not in df.columns else df)
        return pl.concat(frames, how="vertical_relaxed") if frames else pl.DataFrame()

    def object_registries(self, participants: list[str] | None = None) -> dict[str, list[dict]]:
        """Each participant's registry in the shape MEMORA-Bench grounds Replay nouns against."""
        out = {}
        known = self.manifest()["participants"]
        for p in participants or self.participants():
            if p not in known:
                continue
            with self.open(p) as store:
                out[p] = [{k: r[k] or "" for k in ("memory_id", "memory_name", "color", "material", "location")}
                          for r in store.rows("object_registry", participant=p)]
        return out

    # -- forgetting ----------------------------------------------------------------------
    def traces(self, participant: str, shared_caches: bool = True) -> list[Path]:
        """Every file and folder of the bank that holds something of one participant: the
        database with its log and shadow files, staged videos, rebuild leftovers, and the
        baseline caches built from it (`shared_caches`: also the embedding cache every
        participant shares, which holds vectors of their texts)."""
        db = self.db_path(participant)
        found = [p for p in sorted(self.path.glob(f"{db.name}*"))]
        found += [p for p in (self.path / ".staging" / participant,) if p.exists()]
        found += sorted((self.path / ".trash").glob(f"{participant}-*")) if (self.path / ".trash").is_dir() else []
        cache = self.path / ".cache"
        if cache.is_dir():
            found += sorted(p for p in cache.iterdir() if re.search(rf"(^|[-_.]){participant}([-_.]|$)", p.name))
            if shared_caches:
                found += sorted(cache.glob("embeddings-*"))
        return found

    def forget(self, participant: str, shared_caches: bool = True) -> list[str]:
        """Remove every trace of one participant (see `traces`) and their manifest entry, write
        mark and index flags. Returns what was removed, one line each. Refuses while another
        process builds the participant."""
        self.db_path(participant)
        if not self.path.is_dir():
            raise BankError(f"{self.path}: no such bank")
        with self.participant_lock(participant):
            removed = []
            for p in self.traces(participant, shared_caches):
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p)
                else:
                    p.unlink(missing_ok=True)
                removed.append(str(p))
            self.forget_seen(participant)
            if self.exists():
                listed = []

                def change(data: dict) -> None:
                    if data["participants"].pop(participant, None) is not None:
                        listed.append(f"{self.manifest_path}: entry {participant}")
                    if data.get("writing", {}).pop(participant, None) is not None:
                        listed.append(f"{self.manifest_path}: unfinished-write mark of {participant}")
                    if not data.get("writing", True):
                        data.pop("writing")
                    if "indexes" in data:
                        self.set_indexes(data, participant, [])
                    flags = [e.get("consolidated", False) for e in data["participants"].values()]
                    if "consolidated" in data:
                        data["consolidated"] = bool(flags) and all(flags)

                self.update_manifest(change)
                removed += listed
        if not removed:
            raise BankError(f"{self.path}: nothing of {participant} here (no database, staged videos, caches or manifest entry)")
        return removed


def parse_participants(text: object, option: str = "--participants") -> list[str] | None:
    """A comma-separated participant list ('P01,P02') as ids, or None for 'all'. An empty list
    ('', ',') is an error, not everyone."""
    if not isinstance(text, str):
        raise BankError(f"{option}: expected participant ids like P01,P02 or 'all', not {text!r}")
    if text.strip().lower() == "all":
        return None
    pids = [p.strip() for p in text.split(",") if p.strip()]
    if not pids:
        raise BankError(f"{option}: no participant given (ids like P01,P02, or 'all')")
    bad = [p for p in pids if not _PID.match(p)]
    if bad:
        raise BankError(f"{option}: {bad[0]!r} is not a participant id like P01")
    return list(dict.fromkeys(pids))


def check_writable(path: str | Path) -> Path:
    """Refuse a bank path that a build could not write, before any slow work (loading a model):
    an empty path, a file, or a directory (or its nearest existing parent) where no file can
    be created."""
    import tempfile

    if not isinstance(path, (str, Path)) or not str(path).strip():
        raise BankError("the bank path is empty; name a directory, e.g. banks/epic")
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise BankError(f"{p}: exists and is not a directory; a bank is a directory")
    parent = p
    while not parent.exists():
        if parent.parent == parent:
            break
        parent = parent.parent
    if not parent.is_dir():
        raise BankError(f"{p}: cannot be created: {parent} is a file, not a directory")
    try:
        with tempfile.NamedTemporaryFile(dir=parent, prefix=".memora-write-check-"):
            pass
    except OSError as exc:
        raise BankError(f"{p}: cannot write here ({exc.strerror or exc}: {parent})") from exc
    if (p / MANIFEST).exists():
        Bank(p).manifest()  # a damaged manifest fails now too
        if not os.access(p / MANIFEST, os.W_OK):
            raise BankError(f"{p / MANIFEST}: not writable")
    return p

"""`Bank`, the one object callers hold: a directory with one Kùzu database per participant and a
manifest. It composes the manifest (`manifest.ManifestFile`), the locks and write marks
(`locks`) and the integrity checks (`integrity.Integrity`), and does itself what needs all
three: opening a participant's database, adding indexes, queries over every participant, and
forgetting a participant."""

from __future__ import annotations

import os
import re
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from memora_graph.bank.derived import DerivedFiles
from memora_graph.bank.integrity import Integrity, verify_default
from memora_graph.bank.locks import WriteMarks, manifest_lock, participant_lock
from memora_graph.bank.manifest import MANIFEST, ManifestFile
from memora_graph.errors import BankError

if TYPE_CHECKING:  # imported where used: a one-shot command that reads persisted stores never loads Kùzu
    import polars as pl

    from memora_graph.store import Store


class Bank:
    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.manifest_file = ManifestFile(self.path)
        # the marks are written through `update_manifest`, like every other change of the manifest
        self.marks = WriteMarks(lambda change: self.update_manifest(change), self.exists)
        self.integrity = Integrity(self.manifest_file)
        self.derived = DerivedFiles(self.manifest_file)  # the records of files derived from each database

    # -- manifest (manifest.ManifestFile) ----------------------------------------------
    @property
    def manifest_path(self) -> Path:
        return self.manifest_file.path

    def exists(self) -> bool:
        return self.manifest_file.exists()

    def manifest(self) -> dict:
        return self.manifest_file.read()

    def init(self, mode: str, embed_model: str, consolidated: bool) -> dict:
        return self.manifest_file.init(mode, embed_model, consolidated)

    def write_manifest(self, data: dict) -> None:
        self.manifest_file.write(data)

    def update_manifest(self, change: Callable[[dict], None]) -> dict:
        """Read, change and write the manifest under its lock."""
        return self.manifest_file.update(change)

    def record_participant(self, participant: str, videos: list[str], counts: dict,
                           annotations: dict[str, str] | None = None, extra: dict | None = None) -> None:
        self.manifest_file.record_participant(participant, videos, counts, annotations, extra)

    set_condition = staticmethod(ManifestFile.set_condition)
    set_indexes = staticmethod(ManifestFile.set_indexes)

    def db_path(self, participant: str) -> Path:
        return self.manifest_file.db_path(participant)

    def participants(self) -> list[str]:
        data = self.manifest()
        self.integrity.notify(data)
        return sorted(data["participants"])

    # -- locks and write marks (locks) -------------------------------------------------
    def manifest_lock(self) -> AbstractContextManager[None]:
        """Exclusive access to the manifest for a read-modify-write, across processes."""
        return manifest_lock(self.path)

    @contextmanager
    def participant_lock(self, participant: str, wait_s: float = 10.0) -> Iterator[None]:
        """Exclusive, across processes, for building or forgetting one participant (see
        `locks.participant_lock`)."""
        self.db_path(participant)
        with participant_lock(self.path, participant, wait_s):
            yield

    def mark_writing(self, participant: str, op: str) -> None:
        self.marks.mark(participant, op)

    def abandon_writing(self, participant: str) -> None:
        self.marks.abandon(participant)

    def clear_writing(self, participant: str) -> None:
        self.marks.clear(participant)

    def writing_here(self, participant: str, data: dict | None = None) -> bool:
        """Whether this process holds the participant's write mark (it is building it)."""
        return WriteMarks.held_here(data or self.manifest(), participant)

    # -- integrity (integrity.Integrity) -----------------------------------------------
    def record_integrity(self, participant: str) -> dict:
        """(Re)record a participant's integrity after a write (see `Integrity.record`).
        `Bank.open(..., read_only=False)` calls it when the store closes."""
        return self.integrity.record(participant)

    def check(self, participant: str, data: dict | None = None) -> None:
        self.integrity.check(participant, data)

    def check_before_build(self, participant: str) -> None:
        self.integrity.check_before_build(participant)

    def checked_db_file(self, participant: str) -> Path:
        return self.integrity.checked_db_file(participant)

    def checked_sha256(self, participant: str) -> str | None:
        return self.integrity.checked_sha256(participant)

    def verify_counts(self, participant: str, store: Store, expected: dict) -> None:
        self.integrity.verify_counts(participant, store, expected)

    def interrupted_message(self, participant: str, mark: dict) -> str:
        return self.integrity.interrupted_message(participant, mark)

    def not_listed(self, participant: str, data: dict) -> str:
        return self.integrity.not_listed(participant, data)

    def notices(self, data: dict | None = None) -> list[tuple[str, str]]:
        return self.integrity.notices(data)

    def notify(self, data: dict, skip: str | None = None) -> None:
        self.integrity.notify(data, skip)

    def remember_verified(self, participant: str, st, sha256: str) -> None:
        """Note that the database file with stat `st` hashed to its recorded `sha256`."""
        self.integrity.verified.remember(participant, st, sha256)

    def forget_seen(self, participant: str) -> None:
        self.integrity.verified.forget(participant)

    # -- opening -------------------------------------------------------------------------
    def open(self, participant: str, read_only: bool = True, check: bool = True, *, verify: bool | None = None,
             op: str = "write", auto_checkpoint: bool = True) -> Store:
        """Open a participant's database after checking it (`check`): against its integrity
        record before Kùzu opens it, then its record counts against the manifest. `verify=False`
        (`--no-verify`; default: on unless MEMORA_NO_VERIFY is set) skips every check knowingly.
        A read-write store records the database's integrity again when it closes; until then the
        manifest's write mark names `op` (a live writer's is "live"). `auto_checkpoint=False`: the
        caller checkpoints (`Store.checkpoint`; the live writer's schedule, form/checkpoint.py)."""
        from memora_graph.store import Store

        data = self.manifest()
        verify = verify_default() if verify is None else verify
        if participant not in data["participants"] and not (not verify and self.db_path(participant).exists()):
            raise BankError(self.not_listed(participant, data))
        ours = self.writing_here(participant, data)  # a build of this process: its content is in flux
        if not ours:
            self.notify(data, skip=participant if verify else None)
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
            store = Store(self.db_path(participant), read_only=read_only, auto_checkpoint=auto_checkpoint,
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

    # -- optional indexes ----------------------------------------------------------------
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

    # -- queries over every participant ------------------------------------------------
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
                          for r in store.rows("_object_registry_all", participant=p)]
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
        # the live writer's intake journal (form/intake.py) and the copies of logs kept before a replay
        found += [p for p in (self.path / ".live" / f"intake-{participant}.jsonl",) if p.exists()]
        found += sorted(self.path.glob(f".recovery/{db.name}-*"))
        found += sorted(self.path.glob(f".recovery/unreplayable-{db.name}-*"))
        # by exact name: `robot` must not take `robot-7`'s files (an id may hold '-' and '_')
        trash = self.path / ".trash"
        found += sorted(p for p in trash.iterdir() if re.fullmatch(rf"{re.escape(participant)}-\d+", p.name)) \
            if trash.is_dir() else []
        cache = self.path / ".cache"
        if cache.is_dir():  # KIND-PARTICIPANT[-KEY][.ext]: flat1d-P01-<hex>.npy, tools-P01, consolidate-P01.json
            try:
                others = [p for p in self.participants() if p != participant]
            except BankError:
                others = []

            def fits(p: str, name: str) -> bool:
                return re.fullmatch(rf"[a-z0-9]+-{re.escape(p)}(?:-[0-9a-f]+)?(?:\.[A-Za-z0-9.]+)?", name) is not None

            # a file that fits a longer id too (robot-7's, for robot) is that person's
            found += sorted(f for f in cache.iterdir() if fits(participant, f.name)
                            and not any(len(o) > len(participant) and fits(o, f.name) for o in others))
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
        ManifestFile(p).read()  # a damaged manifest fails now too
        if not os.access(p / MANIFEST, os.W_OK):
            raise BankError(f"{p / MANIFEST}: not writable")
    return p

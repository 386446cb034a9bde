"""A memory bank: a directory with one Kùzu database per participant and a manifest.

Memory is personal: one file per person means a build of one participant never locks
another's memory, and forgetting a person is deleting one file. The manifest records what a
build wrote (videos, record counts); opening a participant checks the database against it,
because Kùzu can open a damaged file and return wrong values.
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import polars as pl

from memora_graph.errors import BankError
from memora_graph.store import Store

MANIFEST = "manifest.json"
FORMAT = 1
_PID = re.compile(r"^P\d{2}$")
CHECKED_COUNTS = ("segments", "entity_records", "state_events", "places")


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
        tmp.write_text(json.dumps(data, indent=2, sort_keys=True))
        os.replace(tmp, self.manifest_path)  # atomic: never a half-written manifest

    def record_participant(self, participant: str, videos: list[str], counts: dict, extra: dict | None = None) -> None:
        """Record a participant's database in the manifest. `extra` sets entry fields a build
        leaves to later steps (`consolidated`, `inferred`, `indexes`): an import brings them along."""
        with self.manifest_lock():
            data = self.manifest()
            entry = {"db": f"{participant}.kuzu", "videos": sorted(videos), "counts": dict(counts)}
            old = data["participants"].get(participant, {})
            # the database keeps its indexes and its inferred knowledge (until consolidation runs again)
            entry.update({k: old[k] for k in ("indexes", "consolidated", "inferred") if k in old})
            for k in ("routines", "preferences"):
                if k in old.get("counts", {}) and k not in counts:
                    entry["counts"][k] = old["counts"][k]
            extra = dict(extra or {})
            indexes = extra.pop("indexes", None)
            entry.update(extra)
            data["participants"][participant] = entry
            if indexes is not None:
                self.set_indexes(data, participant, indexes)
            if "consolidated" in extra:
                self.set_condition(data)
            self.write_manifest(data)

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
                store.close()
            with self.manifest_lock():
                data = self.manifest()
                self.set_indexes(data, p, have)
                self.write_manifest(data)
            out[p] = {"created": created, "indexes": have, "seconds": time.perf_counter() - t0}
            if on_participant:
                on_participant(p, out[p])
        return out

    # -- participants ------------------------------------------------------------------
    def participants(self) -> list[str]:
        return sorted(self.manifest()["participants"])

    def db_path(self, participant: str) -> Path:
        if not _PID.match(participant):
            raise BankError(f"participant must look like P01, not {participant!r}")
        return self.path / f"{participant}.kuzu"

    def open(self, participant: str, read_only: bool = True, check: bool = True) -> Store:
        data = self.manifest()
        if participant not in data["participants"]:
            known = ", ".join(sorted(data["participants"])) or "none"
            raise BankError(f"{self.path}: participant {participant} is not in this bank (has: {known})")
        store = Store(self.db_path(participant), read_only=read_only)
        if check:
            try:
                self.verify(participant, store, data["participants"][participant]["counts"])
            except BaseException:
                store.close()
                raise
        return store

    def verify(self, participant: str, store: Store, expected: dict) -> None:
        try:
            got = {k: int(v or 0) for k, v in store.run("store_counts", participant=participant).to_dicts()[0].items()}
        except Exception as exc:
            raise BankError(f"{self.db_path(participant)}: cannot read the database ({exc}); it is damaged. Delete it and rebuild {participant}.") from exc
        diff = {k: (expected.get(k), got.get(k)) for k in CHECKED_COUNTS if expected.get(k) != got.get(k)}
        if diff:
            detail = ", ".join(f"{k} manifest={a} database={b}" for k, (a, b) in diff.items())
            raise BankError(
                f"{self.db_path(participant)}: does not match {MANIFEST} ({detail}). The database is damaged or a build "
                f"was interrupted; run `memora build {self.path} --participants {participant}` to resume."
            )

    def run_each(self, name: str, participants: list[str] | None = None, **params) -> pl.DataFrame:
        """Run a named query over each participant's database and concatenate the frames."""
        frames = []
        for p in participants or self.participants():
            with self.open(p) as store:
                df = store.run(name, participant=p, **params)
            frames.append(df.with_columns(pl.lit(p).alias("participant")).select(["participant", *df.columns]) if "participant" not in df.columns else df)
        return pl.concat(frames, how="vertical_relaxed") if frames else pl.DataFrame()

    def object_registries(self, participants: list[str] | None = None) -> dict[str, list[dict]]:
        """Each participant's registry in the shape MEMORA-Bench grounds Replay nouns against."""
        out = {}
        for p in participants or self.participants():
            if p not in self.manifest()["participants"]:
                continue
            with self.open(p) as store:
                out[p] = [{k: r[k] or "" for k in ("memory_id", "memory_name", "color", "material", "location")}
                          for r in store.rows("object_registry", participant=p)]
        return out


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

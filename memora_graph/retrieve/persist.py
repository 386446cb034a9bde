"""What the in-process recipe reads, persisted next to the bank, so that opening a participant for
one tool call maps files instead of querying Kùzu and recomputing.

Per participant, `BANK/.cache/tools-PXX/` holds the embedding matrices (L2-normalised, one
memory-mapped `.npy` per table with its ids), the BM25 index of every table (posting arrays and
document lengths, memory-mapped `.npy`), every segment row as `_tool_segment` reads one (retrieve/rows.py), the distinct rows of a large
embedding matrix (scanned
instead of every row: search.py, `VectorTable.sims`), the observation graph (entity <-> segment arrays and
co-occurrence counts, memory-mapped `.npy`), the history index (every entity's history summary and
history in order, memory-mapped `.npy`: retrieve/history.py), the activity log's steps (video, time,
segment and wording of every narrated step, memory-mapped `.npy`, and the distinct wordings: what
`ask` reads, retrieve/steps.py) and the rows of the small participant-wide tool
queries (entity registry, places, videos, routines, preferences, inferred links). Nothing is
parsed or rebuilt whole at open: at 1,000 h the JSON postings and observation rows took 7 s.

`meta.json` records the sha256 of every file and the sha256 of the database they were computed
from, as the bank's manifest records it (memora_graph/integrity/): after any write to the database
(a rebuild, `memora consolidate`, `memora index`) the files are stale and are not used. The same
hashes, with those of `meta.json` and `verified.json`, are recorded in the bank's manifest
(`derived.tools` of the participant's entry, memora_graph/bank/derived.py), tied to the database's
recorded sha256: the files are checked against that record, so editing a file and its meta.json
(or its stamps) does not make it trusted. A file whose hash no longer matches its record is
damaged: it is not used either, and a warning names it.
Either way the view reads Kùzu instead and writes the files again (where the bank is writable).
Hashing every file at each open cost 0.6 s at 1,000 h, so a process that hashed them all (or
wrote them: `_stamp_written`) records each file's size, inode and change times in
`verified.json`; a later open hashes again only a
file whose stat differs (any write through the file system changes it), or one changed less than
`RACY_S` before it was verified (a write within the file system's timestamp granularity, as git
treats a "racily clean" file). `memora verify` always hashes every file.

Everything here is computed by the `MemoryView` code itself (`write` warms a view on the database
and saves what it loaded), so tool results are the same whichever way a view was opened
(tests/retrieve/test_persist.py compares them).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from pathlib import Path

import numpy as np

from memora_graph.bank import MANIFEST, Bank
from memora_graph.errors import BankError
from memora_graph.form import live_journal
from memora_graph.retrieve.graph import ObservationGraph
from memora_graph.retrieve.history import ARRAYS as HISTORY_ARRAYS
from memora_graph.retrieve.history import HistoryIndex
from memora_graph.retrieve.rows import ARRAYS as KEYED_ARRAYS
from memora_graph.retrieve.rows import KeyedRows
from memora_graph.retrieve.search import TABLES, Bm25, VectorTable
from memora_graph.retrieve.steps import ARRAYS as STEP_ARRAYS
from memora_graph.retrieve.steps import StepRows

FORMAT = 4  # 3: the history index (retrieve/history.py), the distinct rows of large vector tables; 4: the
# activity log's steps (retrieve/steps.py)
RACY_S = 2.0  # a file changed this close to its verification is hashed again
STAMP_WAIT_BYTES = 64 << 20  # the writer waits out RACY_S for its young files when they hold this much
DIRNAME = "tools-{participant}"
RECORD = "tools"  # their record in the manifest (bank/derived.py)
# named queries of one key whose every row is kept (retrieve/rows.py): the query giving them all, and
# for a query giving a list of rows per key, the key column and the columns its rows are ordered by
KEYED_QUERIES = {"_tool_segment": ("_tool_segment_rows", None, ()),
                 "_tool_video_events": ("_tool_video_events_all", "video", ("t", "ord"))}
# participant-wide named queries (no parameter but $participant) whose rows are kept
# (the observation rows are kept as the graph's arrays; the segment texts only feed BM25, kept as its arrays)
ROW_QUERIES = ("_tool_entities", "_tool_places", "_tool_videos", "_tool_routines", "_tool_preferences",
               "_tool_inferred_links")
BM25_ARRAYS = ("offsets", "docs", "tfs", "lengths")
UNIQUE_ARRAYS = ("rows", "inverse")
GRAPH_ARRAYS = ("segments", "seg_offsets", "seg_entities", "place_offsets", "place_loc", "place_n", "pairs", "counts")

log = logging.getLogger("memora_graph.integrity")


class StaleStores(Exception):
    """The persisted files do not belong to the database as it is now (or are damaged)."""

    @property
    def damaged(self) -> bool:
        return "damaged" in str(self) or "unreadable" in str(self)


def store_dir(bank_path: str | Path, participant: str) -> Path:
    return Path(bank_path) / ".cache" / DIRNAME.format(participant=participant)


def _sha256(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


class PersistedStores:
    """One participant's persisted tool stores, checked against the database's recorded sha256.
    Files are hashed when first read (each once), so a damaged one is never used."""

    def __init__(self, root: Path, meta: dict, record: dict | None = None, bank_path: Path | None = None):
        self.root, self.meta = root, meta
        self.record = record or {"of": meta.get("db_sha256"), "files": meta.get("files", {})}
        self.bank_path = bank_path
        self._checked: set[str] = set()
        self.journal: list[dict] = []  # moments remembered since (replayed by the view: `MemoryView.replay`)
        self.db_now = self.record.get("of")

    @classmethod
    def open(cls, bank_path: str | Path, participant: str, db_sha256: str | None,
             embed_model: str | None, trust_stamps: bool = True, record: dict | None | bool = True) -> PersistedStores:
        """The stores of a participant, or StaleStores saying why they cannot be used. Every file
        is hashed, except (`trust_stamps`) one whose stat is that recorded when it was last hashed.
        The hashes are those of the manifest's record (`record`: True reads it from the bank's
        manifest; a dict is that record): stores with none for this database are not used."""
        root = store_dir(bank_path, participant)
        try:
            raw = (root / "meta.json").read_bytes()
            meta = json.loads(raw)
        except FileNotFoundError:
            raise StaleStores(f"{root}: none persisted") from None
        except (OSError, ValueError) as exc:
            raise StaleStores(f"{root / 'meta.json'}: unreadable ({exc})") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise StaleStores(f"{root}: written in another format")
        journal = None  # the moments remembered since the stores' database (form/live_journal.py)
        if db_sha256 and meta.get("db_sha256") != db_sha256:
            journal = live_journal.usable(Bank(bank_path), participant, meta.get("db_sha256"), db_sha256)
        if not db_sha256 or (meta.get("db_sha256") != db_sha256 and journal is None):
            raise StaleStores(f"{root}: computed from another version of {participant}.kuzu (stale)")
        if meta.get("participant") != participant or meta.get("embed_model") != embed_model:
            raise StaleStores(f"{root}: computed for another participant or embedding model")
        if record is True:
            record = Bank(bank_path).derived.get(participant, RECORD)
        if not isinstance(record, dict) or record.get("of") != meta.get("db_sha256") \
                or not isinstance(record.get("files"), dict):
            raise StaleStores(f"{root}: not recorded in {MANIFEST} for this version of {participant}.kuzu "
                              "(written before stores were recorded there, or by a write that did not finish)")
        files = meta.get("files")
        if _sha256_bytes(raw) != record.get("meta") or files != record["files"]:
            named = sorted(n for n in set(record["files"]) | set(files if isinstance(files, dict) else {})
                           if not isinstance(files, dict) or files.get(n) != record["files"].get(n))
            what = f" (its sha256 of {', '.join(named)} differ from those recorded)" if named else ""
            raise StaleStores(f"{root / 'meta.json'}: damaged: it does not match its record in {MANIFEST}{what}; "
                              f"{', '.join(str(root / n) for n in named) or 'its files'} cannot be trusted")
        stores = cls(root, meta, record, Path(bank_path))
        stores.db_now = db_sha256  # the database now: what a record written by this open is tied to
        if journal is not None:
            try:
                stores.journal = live_journal.read(bank_path, participant, journal)
            except (OSError, ValueError) as exc:
                raise StaleStores(f"{exc}: damaged; the stores of the database before it cannot be brought "
                                  "up to date with it") from None
        stores._opened_ns = time.time_ns()  # before any hashing: what a stamp recorded later may vouch for
        stamps = {} if not trust_stamps else stores._stamps()
        hashed = False
        for name in record["files"]:
            if name in stamps and stamps[name] == _stat_stamp(root / name):
                stores._checked.add(name)  # unchanged since a process hashed it
            else:
                stores._path(name)
                hashed = True
        if trust_stamps and hashed:  # (a stamp whose file changed since, e.g. a copied bank, is replaced too)
            stores._record_stamps()
        return stores

    def _stamps(self) -> dict[str, list[int]]:
        """The stat stamps of the files a process hashed, those changed RACY_S before it only."""
        try:
            raw = (self.root / "verified.json").read_bytes()
            data = json.loads(raw)
        except (OSError, ValueError):
            return {}
        if _sha256_bytes(raw) != self.record.get("stamps"):  # not the stamps the manifest recorded
            return {}
        if not isinstance(data, dict) or data.get("db_sha256") != self.meta.get("db_sha256"):
            return {}
        at, files = data.get("at_ns"), data.get("files")
        if not isinstance(at, int) or not isinstance(files, dict):
            return {}
        racy = at - int(RACY_S * 1e9)
        return {n: st for n, st in files.items() if isinstance(st, list) and len(st) == 4 and max(st[2], st[3]) < racy}

    def _record_stamps(self) -> None:
        """Record the stat of every file just hashed (best effort: a read-only bank keeps hashing).
        The time recorded is the open's start, before the hashing: a file changed while it was
        being hashed has a change time after it, so its stamp is not trusted."""
        at = self.__dict__.get("_opened_ns") or time.time_ns()
        try:
            files = {n: _stat_stamp(self.root / n) for n in self._checked}
            text = json.dumps({"db_sha256": self.meta.get("db_sha256"), "at_ns": at, "files": files})
            if self.bank_path is not None:  # the manifest first: stamps it does not vouch for are ignored
                record = {**self.record, "stamps": _sha256_bytes(text.encode())}
                if not Bank(self.bank_path).derived.put(self.meta.get("participant"), RECORD, record,
                                                        db_sha256=self.db_now):
                    return
                self.record = record
            tmp = self.root / f".verified.{os.getpid()}.tmp"
            tmp.write_text(text)
            os.replace(tmp, self.root / "verified.json")
        except (OSError, BankError):
            pass

    def _path(self, name: str) -> Path:
        """A file of the stores, after checking its sha256 against the manifest's record (once per process)."""
        files = self.record["files"]
        if name not in files:
            raise StaleStores(f"{self.root / name}: not recorded in {MANIFEST}")
        path = self.root / name
        if name not in self._checked:
            try:
                digest = _sha256(path)
            except OSError as exc:
                raise StaleStores(f"{path}: unreadable ({exc})") from None
            if digest != files[name]:
                raise StaleStores(f"{path}: damaged (its sha256 does not match its record in {MANIFEST})")
            self._checked.add(name)
        return path

    def has_rows(self, query: str) -> bool:
        return f"rows{query}.json" in self.meta.get("files", {})

    def rows(self, query: str) -> list[dict]:
        return self._read(f"rows{query}.json", lambda p: json.loads(p.read_text()))

    def vectors(self, table: str) -> VectorTable:
        ids = self._read(f"ids-{table}.json", lambda p: json.loads(p.read_text()))

        def load(path: Path) -> VectorTable:
            mat = np.load(path, mmap_mode="r", allow_pickle=False)
            if mat.ndim != 2 or mat.shape[0] != len(ids):
                raise ValueError(f"{mat.shape} vectors for {len(ids)} ids")
            return VectorTable.normalized(ids, mat)

        vt = self._read(f"vectors-{table}.npy", load)
        if f"unique-{table}.json" in self.meta.get("files", {}):
            def distinct(p: Path) -> VectorTable:
                # the distinct rows are read into memory, not mapped: every search streams them
                # whole, and from the page cache's mapping that read cost ~15% more CPU (~2 ms a
                # search at 1,000 h) than from the process's own (huge-page) memory; the
                # mapping's pages were resident anyway, so the process holds no more than before
                header, arrays = self._arrays(f"unique-{table}", UNIQUE_ARRAYS, in_memory=("rows",))
                return vt.with_unique(arrays["rows"], arrays["inverse"], int(header["head"]))

            vt = self._read(f"unique-{table}.json", distinct)
        return vt

    def _arrays(self, prefix: str, names: tuple[str, ...],
                in_memory: tuple[str, ...] = ()) -> tuple[dict, dict[str, np.ndarray]]:
        """(header, arrays): each array memory-mapped, those named in `in_memory` read whole."""
        header = json.loads(self._path(f"{prefix}.json").read_text())
        return header, {n: np.load(self._path(f"{prefix}-{n}.npy"), mmap_mode=None if n in in_memory else "r",
                                   allow_pickle=False) for n in names}

    def bm25(self, table: str) -> Bm25:
        return self._read(f"bm25-{table}.json", lambda p: Bm25.from_arrays(*self._arrays(f"bm25-{table}", BM25_ARRAYS)))

    def has_graph(self) -> bool:
        return "graph.json" in self.meta.get("files", {})

    def graph(self) -> ObservationGraph:
        return self._read("graph.json", lambda p: ObservationGraph.from_arrays(*self._arrays("graph", GRAPH_ARRAYS)))

    def has_keyed(self, query: str) -> bool:
        return f"keyed{query}.json" in self.meta.get("files", {})

    def keyed(self, query: str) -> KeyedRows:
        return self._read(f"keyed{query}.json",
                          lambda p: KeyedRows.from_arrays(*self._arrays(f"keyed{query}", KEYED_ARRAYS)))

    def has_history(self) -> bool:
        return "history.json" in self.meta.get("files", {})

    def history(self) -> HistoryIndex:
        return self._read("history.json", lambda p: HistoryIndex.from_arrays(*self._arrays("history", HISTORY_ARRAYS)))

    def has_steps(self) -> bool:
        return "steps.json" in self.meta.get("files", {})

    def steps(self) -> StepRows:
        return self._read("steps.json", lambda p: StepRows.from_arrays(*self._arrays("steps", STEP_ARRAYS)))

    def _read(self, name: str, read):
        """`read(path)` of a checked file; a file whose hash was recorded but which does not
        read (truncated, then recorded again by hand) is damaged, not a traceback."""
        path = self._path(name)
        try:
            return read(path)
        except (OSError, ValueError, TypeError, KeyError, IndexError, RecursionError) as exc:
            raise StaleStores(f"{path}: damaged (it does not read: {type(exc).__name__}: {exc})") from None


def _sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _stat_stamp(path: Path) -> list[int]:
    st = path.stat()
    return [st.st_size, st.st_ino, st.st_mtime_ns, st.st_ctime_ns]


def _stamp_written(root: Path, files: dict[str, str], db_sha256: str) -> str | None:
    """Record, as a reader that hashed them would (`verified.json`), the stat of the files this
    process just wrote and hashed, so that the first open in another process reads their stat
    instead of hashing them all (1.5 GB, 2.2 CPU-s at 1,000 h). The files are in a directory of
    this process's own (renamed into place afterwards, which leaves their stat as it is), so their
    bytes are the hashed ones when the stamp is taken; a stamp counts only for a file changed
    RACY_S before it, as for a reader's. Where the files still that young hold STAMP_WAIT_BYTES
    or more, the writer waits until they are old enough (at most RACY_S); smaller young files
    are left to the first open to hash. Returns the sha256 of the stamps written, if any."""
    racy_ns = int(RACY_S * 1e9)
    stats = {n: _stat_stamp(root / n) for n in files}
    now = time.time_ns()
    young = [st for st in stats.values() if max(st[2], st[3]) >= now - racy_ns]
    if young and sum(st[0] for st in young) >= STAMP_WAIT_BYTES:
        time.sleep((max(max(st[2], st[3]) for st in young) + racy_ns - now) / 1e9 + 0.01)
    at = time.time_ns()
    stamps = {}
    for n in files:
        st = _stat_stamp(root / n)
        if max(st[2], st[3]) < at - racy_ns:
            stamps[n] = st
    if stamps:
        text = json.dumps({"db_sha256": db_sha256, "at_ns": at, "files": stamps})
        (root / "verified.json").write_text(text)
        return _sha256_bytes(text.encode())
    return None


def write(view, bank_path: str | Path, db_sha256: str, embed_model: str | None, release: bool = False) -> Path:
    """Warm `view` (open on the database) and persist what it loaded. The directory is replaced
    whole (written aside, then renamed), so a reader sees the old files or the new ones.
    `release`: drop each part from the view once it is written (the caller only wants the
    files), so that the write holds one part at a time."""
    root = store_dir(bank_path, view.participant)
    tmp = root.with_name(f".{root.name}.{os.getpid()}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        files = {}

        def put(name: str, write_fn) -> None:
            write_fn(tmp / name)
            files[name] = _sha256(tmp / name)

        def put_arrays(prefix: str, header: dict, arrays: dict[str, np.ndarray]) -> None:
            put(f"{prefix}.json", lambda p: p.write_text(json.dumps(header, ensure_ascii=False)))
            for n, a in arrays.items():
                put(f"{prefix}-{n}.npy", lambda p, a=a: np.save(p, np.ascontiguousarray(a), allow_pickle=False))

        for query in ROW_QUERIES:
            rows = view.fetch(query)
            text = json.dumps(rows, ensure_ascii=False)
            if json.loads(text) != rows:  # a value JSON does not carry exactly: leave it to Kùzu
                continue
            put(f"rows{query}.json", lambda p, t=text: p.write_text(t))
        for table in TABLES:
            vt = view.vectors(table)
            put(f"ids-{table}.json", lambda p, v=vt: p.write_text(json.dumps(v.ids)))
            put(f"vectors-{table}.npy", lambda p, v=vt: np.save(p, np.ascontiguousarray(v.mat), allow_pickle=False))
            put_arrays(f"bm25-{table}", *view.bm25(table).arrays())
            unique = vt.unique_rows()
            if unique is not None:  # the table's distinct rows: scanned instead of all (search.py, VectorTable.sims)
                put_arrays(f"unique-{table}", {"head": unique[2]}, {"rows": unique[0], "inverse": unique[1]})
            del vt, unique
            if release:
                view.release(table)
        put_arrays("graph", *view.graph.arrays())
        if release:
            view.release()
        put_arrays("history", *HistoryIndex.build(view.frame("_tool_history_all")).arrays())
        put_arrays("steps", *StepRows.build(view.frame("_open_action_log").iter_rows(named=True)).arrays())
        for query, (every, group, order) in KEYED_QUERIES.items():
            frame = view.frame(every)
            rows = KeyedRows.build(frame) if group is None else KeyedRows.build_grouped(frame, group, order)
            del frame
            put_arrays(f"keyed{query}", *rows.arrays())
            del rows
        meta = {"format": FORMAT, "participant": view.participant, "db_sha256": db_sha256,
                "embed_model": embed_model, "files": files}
        meta_text = json.dumps(meta, indent=1, sort_keys=True)
        (tmp / "meta.json").write_text(meta_text)
        stamps = _stamp_written(tmp, files, db_sha256)
        record = {"of": db_sha256, "meta": _sha256_bytes(meta_text.encode()), "stamps": stamps, "files": files}
        if root.exists():
            old = root.with_name(f".{root.name}.{os.getpid()}.old")
            try:
                root.rename(old)
            except FileNotFoundError:  # another process replaced them first
                pass
            shutil.rmtree(old, ignore_errors=True)
        try:
            tmp.rename(root)
        except OSError:
            if not root.is_dir():
                raise
            shutil.rmtree(tmp, ignore_errors=True)  # another process wrote them meanwhile: theirs stand
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    # recorded in the manifest last: files it has no record of are never read (a write of the
    # database since, or a manifest that cannot be written, leaves them unused: computed again)
    try:
        Bank(bank_path).derived.put(view.participant, RECORD, record, db_sha256=db_sha256)
    except (OSError, BankError) as exc:
        log.warning(f"{bank_path}: could not record {view.participant}'s tool stores in {MANIFEST} ({exc}); "
                    "they are not read until they are")
    return root

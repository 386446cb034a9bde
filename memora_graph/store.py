"""The only module that imports kuzu: open a participant database, migrate, query, bulk-load.

Kùzu errors become `StoreError`s that say what happened in a user's words (locked by another
process, not a database, read-only, syntax error), always naming the database path.
"""

from __future__ import annotations

import ctypes
import errno
import hashlib
import os
import re
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

import kuzu
import polars as pl

from memora_graph import schema
from memora_graph.errors import DiskFullError, QueryTimeout, StoreError
from memora_graph.paths import SCHEMA_DIR
from memora_graph.queries import NamedQuery, bind, get_query

_INDEX_DDL = re.compile(r"CREATE_(?:FTS|VECTOR)_INDEX\(\s*'(\w+)'\s*,\s*'(\w+)'")
INDEX_DIR = SCHEMA_DIR / "indexes"


FULL_BYTES = 1 << 20  # below this much free space a failed write is taken for a full disk


def free_bytes(path: Path) -> int | None:
    """Bytes the filesystem holding `path` can still take (as root: reserved blocks included)."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        st = os.statvfs(p)
    except OSError:
        return None
    return st.f_bfree * st.f_frsize if os.geteuid() == 0 else st.f_bavail * st.f_frsize


def disk_full(exc: BaseException, path: Path) -> bool:
    """Whether a failed write failed for lack of space: the OS said so, or (Kùzu often reports
    only "Invalid transaction type to rollback") the filesystem has next to nothing left."""
    if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
        return True
    if "no space left on device" in str(exc).lower():
        return True
    free = free_bytes(path)
    return free is not None and free < FULL_BYTES


def disk_full_message(path: Path, needed_mb: float | None = None) -> str:
    free = free_bytes(path)
    need = f" (needed about {needed_mb:.0f} MB" + (f", {free / 1e6:.0f} MB free" if free is not None else "") + ")" \
        if needed_mb else (f" ({free / 1e6:.1f} MB free)" if free is not None else "")
    return f"{path}: no space left on device{need}. Free some space and re-run the command."


def translate_error(exc: Exception, path: Path, cypher: str | None = None) -> StoreError:
    msg = str(exc)
    low = msg.lower()
    if "could not set lock" in low:
        return StoreError(f"{path}: the database is locked by another process (is a `memora build` still running?). Wait for it to finish, or stop it, then retry.")
    if "not a valid kuzu database" in low or "unable to open database" in low:
        return StoreError(f"{path}: not a memora/Kùzu database file (damaged, or some other file).")
    if "read-only" in low or "read only" in low:
        if "cannot create an empty database" in low:
            return StoreError(f"{path}: no database here (nothing to open read-only). Build it first with `memora build`.")
        return StoreError(f"{path}: this database is open read-only; pass --write to allow writes.")
    if low.strip() == "interrupted.":  # Connection.set_query_timeout ran out (or interrupt())
        return QueryTimeout(f"{path}: the query ran past its time limit and was stopped; nothing it did was kept "
                            "(narrow it, or give it more time with --timeout SECONDS)")
    if "parser exception" in low:
        detail = msg.split("Parser exception:", 1)[-1].strip()
        return StoreError(f"Cypher syntax error: {detail}")
    if "binder exception" in low:
        detail = msg.split("Binder exception:", 1)[-1].strip()
        return StoreError(f"Cypher error: {detail}")
    if "path cannot be a directory" in low:
        return StoreError(f"{path}: is a directory, not a database file.")
    return StoreError(f"{path}: {msg}")


def wal_path(db: Path) -> Path:
    """Kùzu's write-ahead log of a database file."""
    return Path(db).with_name(Path(db).name + ".wal")


MB = 1 << 20
REPLAY_FACTOR = 32  # buffer pool per byte of log, to start with (replay took 26-28: see replay_pool_bytes)
REPLAY_MIN = 256 * MB


def replay_pool_bytes(log_bytes: int) -> int:
    """A buffer pool that leaves room to replay a write-ahead log of `log_bytes`: Kùzu keeps
    every change replayed from the log in memory until the next checkpoint, and the smallest
    pools that replayed live writers' logs were 26-28 bytes per byte of log (4.5 MB: 126 MB,
    8.7 MB: 236 MB, 15.5 MB: between 360 and 420 MB; 256 MB, the cap before, failed on the
    last). `memora_graph.integrity.probe` doubles it while Kùzu still says it is short."""
    return max(REPLAY_MIN, REPLAY_FACTOR * log_bytes)


def pool_full(exc: BaseException) -> bool:
    """Whether Kùzu failed for want of buffer pool."""
    low = str(exc).lower()
    return "buffer pool is full" in low or "unable to allocate memory" in low


class ReplayError(StoreError):
    """A database that could not be opened with the write-ahead log next to it (`log_bytes`)."""

    def __init__(self, message: str, log_bytes: int, short_of_pool: bool = False):
        super().__init__(message)
        self.log_bytes = log_bytes
        self.short_of_pool = short_of_pool


def replay_failure(db: Path, log_bytes: int, exc: BaseException, pool: int = 0) -> str:
    """What to say when a database cannot be opened with its write-ahead log: the file, the
    log and its size, why, and what to do."""
    wal = wal_path(db)
    why = str(translate_error(exc, db)).removeprefix(f"{db}: ")
    head = f"{db}: cannot be opened with its write-ahead log {wal.name} ({log_bytes / MB:.1f} MB of changes since " \
           f"its last checkpoint): {why}."
    db = Path(db)
    bank, who = (db.parent, db.stem) if re.fullmatch(r"P\d{2}", db.stem) else ("BANK", "PARTICIPANT")
    if pool_full(exc):
        given = f"the {pool / MB:.0f} MB buffer pool given" if pool else "the buffer pool this machine allows"
        return (f"{head} Replaying the log needs more memory than {given} (about {REPLAY_FACTOR} x the log's "
                f"size: {replay_pool_bytes(log_bytes) / MB:.0f} MB is expected to do). Nothing was changed: "
                f"`memora verify {bank} --accept {who}` replays it on a machine with "
                f"that much free memory (it sizes the pool from the log and keeps a copy of the log first).")
    return (f"{head} Nothing was changed. The log may be damaged or belong to another database: keep a copy of "
            f"{wal} before anything else; `memora verify {bank}` reports it; moving the log away opens the "
            f"database as of its last checkpoint, losing the writes in the log.")


_ABANDONED: list = []  # Kùzu handles of databases whose write ran out of space; never destroyed


class Store:
    """One Kùzu database (one participant's memory), opened read-only unless asked otherwise."""

    def __init__(self, path: str | Path, read_only: bool = True, bulk: bool = False,
                 on_close: Callable[[Store], None] | None = None, on_fail: Callable[[Store], None] | None = None,
                 buffer_pool_bytes: int = 0, auto_checkpoint: bool = True):
        """`bulk=True` (builds) defers checkpoints to `close()`: a commit then only appends to
        the write-ahead log, which is still replayed after a crash, so nothing committed is lost.
        `auto_checkpoint=False` does too (the live writer checkpoints on its own schedule, with
        `checkpoint()`: Kùzu's automatic one runs inside COMMIT and, when it fails, fails a commit
        that was kept). `on_close(store)` runs after a clean close (the bank records a written
        database's integrity there); it does not run when the close failed: `on_fail(store)` does.
        `buffer_pool_bytes` caps Kùzu's page cache (0: Kùzu's default, most of the memory); a
        cap must leave room to replay the write-ahead log (`replay_pool_bytes`)."""
        self.path = Path(path)
        self.read_only = read_only
        self.on_close = on_close
        self.on_fail = on_fail
        self._broken: StoreError | None = None
        if read_only and not self.path.exists():
            raise StoreError(f"{self.path}: no database here. Build it first with `memora build`.")
        if self.path.exists() and self.path.is_file() and self.path.stat().st_size == 0:
            # Kùzu would silently open a 0-byte file as a new, empty database.
            raise StoreError(f"{self.path}: empty file, not a database (a build that never started?). Delete it and rebuild.")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        wal = wal_path(self.path)
        log_bytes = wal.stat().st_size if wal.exists() else 0
        try:
            self._db = kuzu.Database(str(self.path), read_only=read_only, auto_checkpoint=auto_checkpoint and not bulk,
                                     buffer_pool_size=buffer_pool_bytes)
            self._conn = kuzu.Connection(self._db)
        except RuntimeError as exc:
            if log_bytes and "could not set lock" not in str(exc).lower():
                raise ReplayError(replay_failure(self.path, log_bytes, exc, buffer_pool_bytes), log_bytes,
                                  pool_full(exc)) from exc
            raise translate_error(exc, self.path) from exc
        self.replayed_bytes = log_bytes  # the write-ahead log found (and replayed) on opening
        self._readers = 0  # open reader() connections (a checkpoint waits for their transactions)
        self._in_tx = False
        self._prepared: dict[str, object] = {}
        self._catalog: dict[str, str] | None = None

    # -- lifecycle ---------------------------------------------------------------------
    def reader(self, counted: bool = True, threads: int = 0) -> Store:
        """A second connection on this open database, read-only by this class's checks, for
        another thread of the same process (live memory consolidates off the request path; a
        writable server's readers read through one): Kùzu serves it a committed snapshot while
        this connection writes. Closing it closes only the connection. `counted`: it may hold a
        long snapshot (a consolidation's), which the writer's checkpoints wait out (`readers`);
        a reader of short queries only (the tools') is not counted. `threads`: the most threads
        Kùzu runs one of its queries on (0: its default, every core)."""
        other = Store.__new__(Store)
        other.path, other.read_only, other.on_close, other.on_fail, other._broken = self.path, True, None, None, None
        other._db, other._shared, other._owner = self._db, True, self if counted else None
        other._conn = kuzu.Connection(self._db, threads)
        other._in_tx, other._prepared, other._catalog = False, {}, None
        other.replayed_bytes, other._readers = 0, 0
        if counted:
            self._readers += 1
        return other

    @property
    def readers(self) -> int:
        """Connections opened with `reader()` and not closed yet."""
        return self._readers

    def wal_bytes(self) -> int:
        """The size of the write-ahead log now (what a crash would leave to replay)."""
        try:
            return wal_path(self.path).stat().st_size
        except FileNotFoundError:
            return 0

    def checkpoint(self) -> None:
        """Write the write-ahead log's changes into the database file and empty the log. Kùzu
        waits (about 6 s at most, then fails) for the transactions of other connections."""
        if self.read_only:
            raise StoreError(f"{self.path}: open read-only; nothing to checkpoint")
        self._execute("CHECKPOINT")

    def close(self) -> None:
        if self._broken is not None:  # abandoned after a full disk: nothing may touch these handles again
            self._failed()
            return
        if getattr(self, "_conn", None) is not None:
            try:
                if not self.read_only:
                    self._execute("CHECKPOINT")
                owner = getattr(self, "_owner", None)
                if owner is not None:
                    owner._readers -= 1
                    self._owner = None
                self._conn.close()
                if not getattr(self, "_shared", False):
                    self._db.close()
            except BaseException:
                self._failed()
                raise
            self._conn = None
            if self.on_close is not None:
                self.on_close(self)

    def _failed(self) -> None:
        hook, self.on_fail = self.on_fail, None
        if hook is not None:
            hook(self)

    def _abandon(self, exc: BaseException) -> DiskFullError:
        """After a write failed for lack of space, Kùzu 0.11.3 spins at 100% CPU in its rollback
        as soon as the connection or database is closed or garbage-collected. The handles are
        kept alive for the rest of the process (an extra reference Python never releases, so not
        even interpreter shutdown destroys them); the OS closes the file at exit, and the write
        was never committed and checkpointed, so the database keeps its last checkpoint."""
        err = DiskFullError(disk_full_message(self.path))
        self._broken = err
        for obj in (getattr(self, "_conn", None), getattr(self, "_db", None)):
            if obj is not None:
                _ABANDONED.append(obj)
                ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))
        self._conn = None
        return err

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- running Cypher ----------------------------------------------------------------
    def _execute(self, cypher: str, params: dict | None = None):
        if self._broken is not None:
            raise self._broken
        try:
            return self._conn.execute(cypher, params or {})
        except RuntimeError as exc:
            if not self.read_only and disk_full(exc, self.path):
                raise self._abandon(exc) from exc
            raise translate_error(exc, self.path, cypher) from exc
        except (TypeError, ValueError, OverflowError) as exc:  # a parameter value Kùzu cannot convert
            raise StoreError(f"{self.path}: Kùzu cannot bind these parameters ({exc})") from exc

    def _damaged(self, exc: Exception) -> StoreError:
        return StoreError(f"{self.path}: the database returned text that is not valid UTF-8 ({exc}); it is damaged. "
                          "Delete it and rebuild the participant with `memora build`.")

    def _frame(self, result) -> pl.DataFrame:
        """A result as a polars frame, its text checked: Kùzu hands over the bytes of a damaged
        string as they are, and polars would carry them until something panics on them."""
        import pyarrow as pa

        try:
            table = result.get_as_arrow(chunk_size=-1)
        except RuntimeError as exc:  # a statement that fails while its rows are fetched
            raise translate_error(exc, self.path) from exc
        try:  # the text columns: a full validate of every column trips over Kùzu's large nested
            for column in table.columns:  # list offsets (a whole node table as structs), which are fine
                if pa.types.is_string(column.type) or pa.types.is_large_string(column.type):
                    column.validate(full=True)
        except pa.ArrowInvalid as exc:
            raise self._damaged(exc) from exc
        return pl.from_arrow(table)

    def set_timeout(self, seconds: float | None) -> None:
        """Stop each later query after `seconds` (Kùzu interrupts it: QueryTimeout); None: never."""
        self._conn.set_query_timeout(0 if seconds is None else max(1, int(seconds * 1000)))

    def interrupt(self) -> None:
        """Stop the query this connection is running now (from another thread); it fails with
        QueryTimeout. A served call past its time budget is stopped so (serve/budget.py)."""
        self._conn.interrupt()

    def query(self, cypher: str, params: dict | None = None) -> pl.DataFrame:
        """Cypher from the library and tests (the `memora query` path goes through the read guard
        first, memora_graph/adhoc.py); writes fail unless opened read-write."""
        result = self._execute(cypher, params)
        if isinstance(result, list):  # several statements: keep the last result
            result = result[-1]
        return self._frame(result)

    def run(self, name: str | NamedQuery, **params) -> pl.DataFrame:
        q = name if isinstance(name, NamedQuery) else get_query(name)
        if q.writes and self.read_only:
            raise StoreError(f"{self.path}: query '{q.name}' writes; the database is open read-only.")
        return self._frame(self._execute(q.cypher, bind(q, params)))

    def rows(self, name: str, **params) -> list[dict]:
        return self.run(name, **params).to_dicts()

    def fetch(self, name: str, **params) -> list[dict]:
        """A named read query as a list of dicts, for the hot path (retrieval tools): the
        statement is prepared once per Store and reused, and no polars frame is built."""
        return self._dicts(self._prepared_result(name, params))

    def _dicts(self, result) -> list[dict]:
        columns = result.get_column_names()
        try:
            return [dict(zip(columns, row)) for row in result.get_all()]
        except UnicodeDecodeError as exc:
            raise self._damaged(exc) from exc

    def fetch_frame(self, name: str, **params) -> pl.DataFrame:
        """A named read query as a polars frame, prepared once as `fetch` is: for many rows of
        few columns on the hot path (one columnar transfer instead of a dict per row)."""
        return self._frame(self._prepared_result(name, params))

    def _prepared_result(self, name: str, params: dict):
        q = get_query(name)
        if q.writes:
            raise StoreError(f"query '{q.name}' writes; fetch() is for reads")
        return self._fetch(q, params)

    def write(self, name: str, **params) -> list[dict]:
        """A named write query, prepared once per Store and reused (the live writer's hot path:
        preparing costs about as much as running one of its small statements)."""
        q = get_query(name)
        if self.read_only:
            raise StoreError(f"{self.path}: query '{q.name}' writes; the database is open read-only.")
        return self._dicts(self._fetch(q, params))

    def _fetch(self, q: NamedQuery, params: dict):
        """The prepared statement's result (prepared once per Store)."""
        bound = bind(q, params)
        if self._broken is not None:
            raise self._broken
        prepared = self._prepared.get(q.name)
        try:
            if prepared is None:
                prepared = self._prepared[q.name] = kuzu.PreparedStatement(self._conn, q.cypher, bound)
            result = self._conn.execute(prepared, bound)
        except RuntimeError as exc:
            if q.writes and disk_full(exc, self.path):
                raise self._abandon(exc) from exc
            raise translate_error(exc, self.path, q.cypher) from exc
        return result

    # -- writes ------------------------------------------------------------------------
    @contextmanager
    def transaction(self) -> Iterator[Store]:
        """All-or-nothing: a killed process or an exception leaves nothing of the block."""
        self._execute("BEGIN TRANSACTION")
        self._in_tx = True
        try:
            yield self
            self._in_tx = False
            self._execute("COMMIT")
        except BaseException:  # the block failed, or its COMMIT was refused (a duplicate key Kùzu finds only
            self._in_tx = False  # then), which left the transaction open: the next one failed ("Write-write conflict")
            try:
                self._execute("ROLLBACK")
            except StoreError:
                pass
            raise

    def tables(self) -> dict[str, str]:
        """Table name -> NODE / REL, from the database's catalog."""
        return dict(self.run("_tables").iter_rows())

    def table_counts(self, participant: str) -> dict[str, dict[str, int]]:
        """Per table of the catalog: its rows, and (node tables) the rows of another participant."""
        got = {r["table_name"]: (int(r["rows"]), int(r["other_participant"])) for r in self.rows("_table_counts", participant=participant)}
        return {t: {"rows": got.get(t, (0, 0))[0], "other_participant": got.get(t, (0, 0))[1]} for t in sorted(self.tables())}

    def copy(self, table: str, frame: pl.DataFrame, from_table: str | None = None, to_table: str | None = None) -> int:
        """Bulk load a polars frame into a table (COPY FROM), the fast path for builds.

        The statement is one of those generated once from schema/*.cypher for this table (and,
        for a rel table with several FROM / TO pairs, this pair), checked against the database's
        catalog; the frame is bound as a parameter and conformed to the schema's columns and
        types (Kùzu maps columns by position). No name given here is formatted into Cypher."""
        if frame.is_empty():
            return 0
        try:
            statement = schema.table(table).copy_statements()[(from_table, to_table)]
        except KeyError:
            pairs = ", ".join(f"{a}->{b}" for a, b in schema.table(table).pairs)
            raise StoreError(f"{self.path}: COPY {table} needs one of its FROM / TO pairs ({pairs}), "
                             f"not {from_table}->{to_table}") from None
        self._check_table(table)
        self._execute(statement, {"frame": schema.conform(table, frame)})
        return frame.height

    def copy_file(self, table: str, path: Path) -> None:
        """Bulk load a Parquet file the caller wrote into a table (COPY FROM the file: Kùzu reads
        it in batches). Its columns are the table's, in the schema's order (`schema.conform`)."""
        statement = schema.table(table).copy_file_statement(Path(path))
        self._check_table(table)
        self._execute(statement)

    def _check_table(self, table: str) -> None:
        """Refuse a COPY into a table the schema has but this database lacks."""
        if self._catalog is None:
            self._catalog = self.tables()
        if table not in self._catalog:
            raise StoreError(f"{self.path}: the schema has table {table!r} but this database does not "
                             "(schema not applied?)")

    # -- schema ------------------------------------------------------------------------
    def apply_schema(self, folder: Path = SCHEMA_DIR) -> list[str]:
        """Apply schema/*.cypher in order, once each; returns the files applied now."""
        files = sorted(folder.glob("*.cypher"))
        if not files:
            raise StoreError(f"{folder}: no schema files found")
        self.run("_schema_bootstrap")
        done = {r["file"]: r["checksum"] for r in self.rows("_schema_applied")}
        applied = []
        for f in files:
            text = f.read_text()
            checksum = hashlib.sha256(text.encode()).hexdigest()[:16]
            if f.name in done:
                if done[f.name] != checksum:
                    raise StoreError(f"{self.path}: schema file {f.name} changed after it was applied (checksum {done[f.name]} -> {checksum}); rebuild the bank.")
                continue
            statements = [s.strip() for s in _strip_comments(text).split(";") if s.strip()]
            with self.transaction():
                for s in statements:
                    self._execute(s)  # the schema file's own DDL, applied as written
                self.run("_schema_record", id=f.name, checksum=checksum,
                         applied_at=datetime.now(timezone.utc).replace(tzinfo=None).isoformat(sep=" "))
            applied.append(f.name)
        self._catalog = None
        return applied

    def indexes(self) -> dict[str, str]:
        """Index name -> table, for the FTS / vector indexes this database has."""
        return dict(self.run("_indexes").iter_rows())

    def ensure_indexes(self, fts: bool = True, hnsw: bool = False, folder: Path = INDEX_DIR) -> list[str]:
        """Create the missing indexes of the kinds asked for; returns those created.
        `fts`: schema/indexes/fts.cypher (the 'fts' / 'kuzu' / 'hnsw' retrieval recipes);
        `hnsw`: schema/indexes/hnsw.cypher (the 'hnsw' recipe). Builds make neither by default.

        Index DDL runs outside any transaction (Kùzu's rule) and after bulk loads (an index is
        built once over the loaded rows; later rows join it automatically). An index is never
        dropped and re-created (a known Kùzu bug with vector indexes)."""
        have = set(self.indexes())
        created = []
        for kind in [k for k, on in (("fts", fts), ("hnsw", hnsw)) if on]:
            for name, statement in index_statements(kind, folder):
                if name not in have:
                    self._execute(statement)
                    created.append(name)
        return created

    def migrations(self) -> list[str]:
        return [r["file"] for r in self.rows("_schema_applied")]

    def migration_checksums(self) -> dict[str, str]:
        """Schema file -> checksum of what was applied (an export carries them, an import compares)."""
        return {r["file"]: r["checksum"] for r in self.rows("_schema_applied")}

    def catalog(self) -> dict[str, dict]:
        """The participant tables this database has, as the schema files define them: name ->
        {"kind": "NODE" | "REL", "columns": [(name, type), ...] in table order, "pairs": [(from, to), ...]
        for a REL}. SchemaMigration, which holds no participant data, is left out."""
        have = self.tables()
        return {t.name: {"kind": t.kind, "columns": [(c.name, c.type) for c in t.columns], "pairs": list(t.pairs)}
                for t in schema.schema_tables().values() if t.name in have and t.name != "SchemaMigration"}


INDEX_KINDS = ("fts", "hnsw")


def index_statements(kind: str, folder: Path = INDEX_DIR) -> list[tuple[str, str]]:
    """(index name, DDL) of one kind of index, from schema/indexes/<kind>.cypher."""
    if kind not in INDEX_KINDS:
        raise StoreError(f"no index kind {kind!r}; kinds: {', '.join(INDEX_KINDS)}")
    out = []
    for statement in (s.strip() for s in _strip_comments((folder / f"{kind}.cypher").read_text()).split(";")):
        m = _INDEX_DDL.search(statement)
        if m:
            out.append((m.group(2), statement))
    return out


def index_names(kind: str) -> list[str]:
    """The names of the indexes of one kind ('fts' or 'hnsw') a database can have."""
    return [name for name, _ in index_statements(kind)]


def _strip_comments(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if not line.strip().startswith("//"))


def rebuild_from_rows(db: Path, aside: Path) -> Path:
    """Write a database again from its rows: EXPORT DATABASE into `aside`, the file moved into
    `aside` (kept, never deleted), IMPORT DATABASE into a new file at `db`, then the optional
    indexes it had made again. Returns where the old file went; on failure the old file is put
    back and the error raised.

    For a database whose write-ahead log was set aside (form/intake.py) after a writer was killed
    inside a checkpoint: the file that checkpoint left can hold a primary-key index that no longer
    matches its rows. Kùzu 0.11.3 then refuses new keys as duplicates at COMMIT ("Found duplicated
    primary key value P09:cup@600" for a key no row holds), so the moments the intake journal
    re-applies were refused, and acknowledged writes were lost (the kill soak found it; the rows
    read and written again took all 387 of that bank's)."""
    db, aside = Path(db), Path(aside)
    rows = aside / "rows"
    src = Store(db, read_only=False)
    try:
        have = set(src.indexes())
        kinds = {k: bool(set(index_names(k)) & have) for k in ("fts", "hnsw")}
        src._execute(schema.export_statement(rows))
    finally:
        src.close()
    (rows / "index.cypher").unlink(missing_ok=True)  # made again below: Kùzu's import of two FTS indexes fails
    old = aside / db.name
    shutil.move(str(db), old)
    try:
        dst = Store(db, read_only=False)
        try:
            dst._execute(schema.import_statement(rows))
            if any(kinds.values()):
                dst.ensure_indexes(fts=kinds["fts"], hnsw=kinds["hnsw"])
        finally:
            dst.close()
    except BaseException:
        for f in (db, wal_path(db)):
            f.unlink(missing_ok=True)
        shutil.move(str(old), db)
        raise
    shutil.rmtree(rows, ignore_errors=True)  # the old file is kept; its rows are in the new one
    return old

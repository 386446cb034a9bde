"""The only module that imports kuzu: open a participant database, migrate, query, bulk-load.

Kùzu errors become `StoreError`s that say what happened in a user's words (locked by another
process, not a database, read-only, syntax error), always naming the database path.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

import kuzu
import polars as pl

from memora_graph.errors import QueryTimeout, StoreError
from memora_graph.paths import SCHEMA_DIR
from memora_graph.queries import NamedQuery, bind, get_query

_MIGRATIONS = (
    "CREATE NODE TABLE IF NOT EXISTS SchemaMigration(id STRING PRIMARY KEY, checksum STRING, applied_at TIMESTAMP)"
)
_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_INDEX_DDL = re.compile(r"CREATE_(?:FTS|VECTOR)_INDEX\(\s*'(\w+)'\s*,\s*'(\w+)'")
INDEX_DIR = SCHEMA_DIR / "indexes"


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


class Store:
    """One Kùzu database (one participant's memory), opened read-only unless asked otherwise."""

    def __init__(self, path: str | Path, read_only: bool = True, bulk: bool = False):
        """`bulk=True` (builds) defers checkpoints to `close()`: a commit then only appends to
        the write-ahead log, which is still replayed after a crash, so nothing committed is lost."""
        self.path = Path(path)
        self.read_only = read_only
        if read_only and not self.path.exists():
            raise StoreError(f"{self.path}: no database here. Build it first with `memora build`.")
        if self.path.exists() and self.path.is_file() and self.path.stat().st_size == 0:
            # Kùzu would silently open a 0-byte file as a new, empty database.
            raise StoreError(f"{self.path}: empty file, not a database (a build that never started?). Delete it and rebuild.")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._db = kuzu.Database(str(self.path), read_only=read_only, auto_checkpoint=not bulk)
            self._conn = kuzu.Connection(self._db)
        except RuntimeError as exc:
            raise translate_error(exc, self.path) from exc
        self._in_tx = False
        self._prepared: dict[str, object] = {}

    # -- lifecycle ---------------------------------------------------------------------
    def close(self) -> None:
        if getattr(self, "_conn", None) is not None:
            if not self.read_only:
                self._execute("CHECKPOINT")
            self._conn.close()
            self._db.close()
            self._conn = None

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- running Cypher ----------------------------------------------------------------
    def _execute(self, cypher: str, params: dict | None = None):
        try:
            return self._conn.execute(cypher, params or {})
        except RuntimeError as exc:
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
        try:
            table.validate(full=True)
        except pa.ArrowInvalid as exc:
            raise self._damaged(exc) from exc
        return pl.from_arrow(table)

    def set_timeout(self, seconds: float | None) -> None:
        """Stop each later query after `seconds` (Kùzu interrupts it: QueryTimeout); None: never."""
        self._conn.set_query_timeout(0 if seconds is None else max(1, int(seconds * 1000)))

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
        q = get_query(name)
        if q.writes:
            raise StoreError(f"query '{q.name}' writes; fetch() is for reads")
        bound = bind(q, params)
        prepared = self._prepared.get(q.name)
        try:
            if prepared is None:
                prepared = self._prepared[q.name] = kuzu.PreparedStatement(self._conn, q.cypher, bound)
            result = self._conn.execute(prepared, bound)
        except RuntimeError as exc:
            raise translate_error(exc, self.path, q.cypher) from exc
        columns = result.get_column_names()
        try:
            return [dict(zip(columns, row)) for row in result.get_all()]
        except UnicodeDecodeError as exc:
            raise self._damaged(exc) from exc

    # -- writes ------------------------------------------------------------------------
    @contextmanager
    def transaction(self) -> Iterator[Store]:
        """All-or-nothing: a killed process or an exception leaves nothing of the block."""
        self._execute("BEGIN TRANSACTION")
        self._in_tx = True
        try:
            yield self
        except BaseException:
            self._in_tx = False
            try:
                self._execute("ROLLBACK")
            except StoreError:
                pass
            raise
        self._in_tx = False
        self._execute("COMMIT")

    def tables(self) -> dict[str, str]:
        df = self._frame(self._execute("CALL show_tables() RETURN name, type"))
        return dict(df.iter_rows())

    def copy(self, table: str, frame: pl.DataFrame, from_table: str | None = None, to_table: str | None = None) -> int:
        """Bulk load a polars frame into a table (COPY FROM), the fast path for builds."""
        if frame.is_empty():
            return 0
        names = [table] + [t for t in (from_table, to_table) if t]
        known = self.tables()
        for n in names:
            if not _IDENT.match(n) or n not in known:
                raise StoreError(f"{self.path}: no table named {n!r}")
        options = f" (from='{from_table}', to='{to_table}')" if from_table and to_table else ""
        # The table name is validated against the catalog above; Kùzu reads `frame` by name.
        self._execute(f"COPY {table} FROM frame{options}")
        return frame.height

    # -- schema ------------------------------------------------------------------------
    def apply_schema(self, folder: Path = SCHEMA_DIR) -> list[str]:
        """Apply schema/*.cypher in order, once each; returns the files applied now."""
        files = sorted(folder.glob("*.cypher"))
        if not files:
            raise StoreError(f"{folder}: no schema files found")
        self._execute(_MIGRATIONS)
        done = dict(self._frame(self._execute("MATCH (m:SchemaMigration) RETURN m.id, m.checksum")).iter_rows())
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
                    self._execute(s)
                self._execute(
                    "CREATE (m:SchemaMigration {id: $id, checksum: $c, applied_at: $t})",
                    {"id": f.name, "c": checksum, "t": datetime.now(timezone.utc).replace(tzinfo=None)},
                )
            applied.append(f.name)
        return applied

    def indexes(self) -> dict[str, str]:
        """Index name -> table, for the FTS / vector indexes this database has."""
        df = self._frame(self._execute("CALL SHOW_INDEXES() RETURN index_name, table_name"))
        return dict(df.iter_rows())

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
        return self._frame(self._execute("MATCH (m:SchemaMigration) RETURN m.id ORDER BY m.id"))["m.id"].to_list()

    def migration_checksums(self) -> dict[str, str]:
        """Schema file -> checksum of what was applied (an export carries them, an import compares)."""
        return dict(self._execute("MATCH (m:SchemaMigration) RETURN m.id, m.checksum ORDER BY m.id").get_as_pl().iter_rows())

    def catalog(self) -> dict[str, dict]:
        """The participant tables as the database defines them: name -> {"kind": "NODE" | "REL",
        "columns": [(name, Kùzu type), ...] in table order, "pairs": [(from, to), ...] for a REL}.
        SchemaMigration, which holds no participant data, is left out."""
        out = {}
        for name, kind in sorted(self.tables().items()):
            if name == "SchemaMigration" or not _IDENT.match(name):
                continue
            # table_info / show_connection take a literal, not a parameter; the name comes from the catalog
            info = self._execute(f"CALL table_info('{name}') RETURN name, type").get_as_pl()
            entry = {"kind": kind, "columns": list(info.iter_rows()), "pairs": []}
            if kind == "REL":
                conn = self._execute(f"CALL show_connection('{name}') RETURN *").get_as_pl()
                entry["pairs"] = [tuple(r[:2]) for r in conn.iter_rows()]
            out[name] = entry
        return out


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

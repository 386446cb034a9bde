"""The tables of a participant database, read once from schema/*.cypher: one source per table.

Staging frames, bulk loads (COPY) and integrity counts take their column lists and types from
here, so a column added to the schema is added everywhere (or fails loudly where a frame lacks
it) instead of being spelled again in Python.

Only the statements the schema files use are understood: `CREATE NODE TABLE T(col TYPE, ...)`,
`CREATE REL TABLE T(FROM A TO B[, FROM C TO D], col TYPE, ...)` and `ALTER TABLE T ADD col TYPE
[DEFAULT ...]`. Anything else in a schema file is applied by Kùzu but ignored here.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import polars as pl

from memora_graph.errors import StoreError
from memora_graph.paths import SCHEMA_DIR

IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_CREATE = re.compile(r"^CREATE\s+(NODE|REL)\s+TABLE\s+(?:IF\s+NOT\s+EXISTS\s+)?(\w+)\s*\((.*)\)\s*$", re.I | re.S)
_ALTER = re.compile(r"^ALTER\s+TABLE\s+(\w+)\s+ADD\s+(?:IF\s+NOT\s+EXISTS\s+)?(\w+)\s+(.+?)(?:\s+DEFAULT\s+.*)?$", re.I | re.S)
_PAIR = re.compile(r"^FROM\s+(\w+)\s+TO\s+(\w+)$", re.I)
_ARRAY = re.compile(r"^FLOAT\[(\d+)\]$", re.I)
_SCALARS = {
    "STRING": pl.String, "INT64": pl.Int64, "DOUBLE": pl.Float64, "BOOLEAN": pl.Boolean,
    "TIMESTAMP": pl.Datetime("us"), "STRING[]": pl.List(pl.String),
}


@dataclass(frozen=True)
class Column:
    name: str
    type: str  # as the schema spells it: STRING, INT64, FLOAT[384], ...

    @property
    def dtype(self) -> pl.DataType:
        m = _ARRAY.match(self.type)
        if m:
            return pl.Array(pl.Float32, int(m.group(1)))
        try:
            return _SCALARS[self.type.upper()]
        except KeyError:
            raise StoreError(f"schema column {self.name}: type {self.type} has no polars equivalent here") from None


@dataclass(frozen=True)
class Table:
    name: str
    kind: str  # "NODE" or "REL"
    columns: tuple[Column, ...]  # properties in schema order (a rel table's FROM / TO keys excluded)
    pairs: tuple[tuple[str, str], ...] = ()  # a rel table's (FROM, TO) node tables

    def names(self, emb: bool = True) -> list[str]:
        """The columns a COPY reads, in order: a rel table starts with its `from` / `to` keys."""
        keys = ["from", "to"] if self.kind == "REL" else []
        return keys + [c.name for c in self.columns if emb or c.name != "emb"]

    def polars_schema(self, emb: bool = True) -> dict[str, pl.DataType]:
        keys = {"from": pl.String, "to": pl.String} if self.kind == "REL" else {}
        return keys | {c.name: c.dtype for c in self.columns if emb or c.name != "emb"}

    def copy_statements(self) -> dict[tuple[str | None, str | None], str]:
        """Every COPY this table takes, generated once from its validated identifiers: the frame
        is bound as $frame (never named in the text). A rel table with several FROM / TO pairs
        needs the pair spelled out, so it has one statement per pair and none without one."""
        if self.kind == "NODE" or len(self.pairs) == 1:
            out = {(None, None): f"COPY {self.name} FROM $frame"}
            if self.pairs:
                out[self.pairs[0]] = out[(None, None)]
            return out
        return {(a, b): f"COPY {self.name} FROM $frame (from='{a}', to='{b}')" for a, b in self.pairs}

    def copy_file_statement(self, path: Path) -> str:
        """The COPY of this table from a Parquet file a build wrote (its bulk load: Kùzu reads a
        file in batches, where a frame bound as $frame is held whole until the commit). Kùzu
        binds only frames as parameters, so the path is written into the statement: it must be
        absolute and hold none of the characters that could end or escape the literal."""
        text = path_literal(path, "a COPY statement")
        if self.kind == "REL" and len(self.pairs) != 1:
            raise StoreError(f"COPY {self.name} from a file needs one FROM / TO pair; it has {len(self.pairs)}")
        return f"COPY {self.name} FROM '{text}'"


def path_literal(path: Path, what: str) -> str:
    """A path as Kùzu's COPY / EXPORT / IMPORT statements take it: Kùzu binds only frames as
    parameters, so the path is written into the statement; it must be absolute and hold none of the
    characters that could end or escape the literal."""
    text = str(path)
    if not Path(text).is_absolute() or any(ch in text for ch in "'\"\\`\n\r\x00"):
        raise StoreError(f"{text}: not a path {what} can name (absolute, no quotes or backslashes)")
    return text


def export_statement(folder: Path) -> str:
    """EXPORT DATABASE into `folder` (every table's rows as Parquet, with the statements that make the
    database again: `import_statement`)."""
    return f"EXPORT DATABASE '{path_literal(folder, 'EXPORT DATABASE')}' (format='parquet')"


def import_statement(folder: Path) -> str:
    """IMPORT DATABASE from a folder `export_statement` wrote, into an empty database."""
    return f"IMPORT DATABASE '{path_literal(folder, 'IMPORT DATABASE')}'"


def _statements(text: str) -> list[str]:
    body = "\n".join(line for line in text.splitlines() if not line.strip().startswith("//"))
    return [" ".join(s.split()) for s in body.split(";") if s.strip()]


def _split_top(text: str) -> list[str]:
    """Split a column list on the commas outside brackets (FLOAT[384], STRING[] stay whole)."""
    parts, depth, cur = [], 0, []
    for ch in text:
        if ch in "([":
            depth += 1
        elif ch in ")]":
            depth -= 1
        if ch == "," and depth == 0:
            parts.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    if "".join(cur).strip():
        parts.append("".join(cur).strip())
    return parts


def _ident(name: str, where: Path) -> str:
    if not IDENT.match(name):
        raise StoreError(f"{where}: {name!r} is not a plain identifier")
    return name


def parse_schema(folder: Path = SCHEMA_DIR) -> dict[str, Table]:
    tables: dict[str, dict] = {}
    for path in sorted(folder.glob("*.cypher")):
        for s in _statements(path.read_text()):
            m = _CREATE.match(s)
            if m:
                kind, name = m.group(1).upper(), _ident(m.group(2), path)
                cols, pairs = [], []
                for part in _split_top(m.group(3)):
                    pair = _PAIR.match(part)
                    if pair:
                        pairs.append((_ident(pair.group(1), path), _ident(pair.group(2), path)))
                        continue
                    col, _, typ = part.partition(" ")
                    typ = re.sub(r"\s+PRIMARY\s+KEY$", "", typ.strip(), flags=re.I)
                    cols.append(Column(_ident(col, path), typ))
                tables[name] = {"kind": kind, "columns": cols, "pairs": pairs}
                continue
            m = _ALTER.match(s)
            if m:
                name = m.group(1)
                if name not in tables:
                    raise StoreError(f"{path}: ALTER TABLE {name} before its CREATE")
                tables[name]["columns"].append(Column(_ident(m.group(2), path), m.group(3).strip()))
    return {n: Table(n, t["kind"], tuple(t["columns"]), tuple(t["pairs"])) for n, t in tables.items()}


@lru_cache(maxsize=2)
def schema_tables(folder: Path = SCHEMA_DIR) -> dict[str, Table]:
    """The tables of schema/*.cypher, parsed once per process."""
    return parse_schema(folder)


def table(name: str) -> Table:
    tables = schema_tables()
    if name not in tables:
        raise StoreError(f"no table {name!r} in the schema (has: {', '.join(sorted(tables))})")
    return tables[name]


def columns(name: str, emb: bool = True) -> list[str]:
    """A table's column names in schema order (`emb=False`: without the embedding)."""
    return table(name).names(emb)


def frame(name: str, rows: list[dict] | None = None, emb: bool = False) -> pl.DataFrame:
    """Rows (dicts with at least the table's columns) as a frame with the schema's columns and
    types, in schema order; extra keys are ignored, a missing one is an error naming it."""
    t = table(name)
    schema = t.polars_schema(emb)
    rows = rows or []
    for r in rows[:1]:
        missing = [c for c in schema if c not in r]
        if missing:
            raise StoreError(f"{name}: row lacks column(s) {', '.join(missing)}")
    return pl.DataFrame([{c: r[c] for c in schema} for r in rows], schema=schema)


def conform(name: str, df: pl.DataFrame, from_table: str | None = None, to_table: str | None = None) -> pl.DataFrame:
    """A frame in the column order and types a COPY into `name` reads (Kùzu maps by position)."""
    schema = table(name).polars_schema()
    missing = [c for c in schema if c not in df.columns]
    if missing:
        raise StoreError(f"COPY {name}: the frame lacks column(s) {', '.join(missing)} (has: {', '.join(df.columns)})")
    return df.select([pl.col(c).cast(dtype) for c, dtype in schema.items()])

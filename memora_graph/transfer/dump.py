"""A participant's memory as plain tables: read out of its database, written to and read from
JSON or Parquet. The unit `memora export` writes and `memora import` loads.

Every node and relationship table is kept whole (ids, every property, embeddings) with the Kùzu
type of each column, so an import rebuilds the same database. Rows are in id order (relationships
by their end points, then properties), not in storage order, which a bulk load does not keep: the
same memory always gives the same export.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import polars as pl

from memora_graph.bank import Bank
from memora_graph.errors import DataError
from memora_graph.ids import RULE, is_participant_id

FORMAT_KEY = "memora_export"
FORMAT_VERSION = 1
PARQUET_META = "export.json"
BANK_LOCAL = ("integrity", "derived")  # manifest fields about this bank's files (its hash, the records of files
# derived from it: bank/derived.py), recorded anew by an import

_SCALARS = {
    "STRING": pl.String, "INT64": pl.Int64, "INT32": pl.Int32, "INT16": pl.Int16, "INT8": pl.Int8,
    "UINT64": pl.UInt64, "UINT32": pl.UInt32, "DOUBLE": pl.Float64, "FLOAT": pl.Float32, "BOOL": pl.Boolean, "BOOLEAN": pl.Boolean,
    "TIMESTAMP": pl.Datetime("us"),
}
_LIST = re.compile(r"^(\w+)\[(\d*)\]$")


def polars_type(kuzu_type: str) -> pl.DataType:
    """The polars dtype a Kùzu column type is read into and bulk-loaded from."""
    if kuzu_type in _SCALARS:
        return _SCALARS[kuzu_type]
    m = _LIST.match(kuzu_type)
    if m and m.group(1) in _SCALARS:
        inner = _SCALARS[m.group(1)]
        return pl.Array(inner, int(m.group(2))) if m.group(2) else pl.List(inner)
    raise DataError(f"column type {kuzu_type} is not supported by memora export")


@dataclass
class DumpedTable:
    """One node table, or one (FROM, TO) pair of a relationship table: its rows as a typed frame.
    A relationship frame starts with the `from` and `to` ids, then its properties."""

    name: str
    kind: str  # "NODE" | "REL"
    columns: list[tuple[str, str]]  # (name, Kùzu type), `from` / `to` first for a REL
    frame: pl.DataFrame
    from_table: str = ""
    to_table: str = ""

    @property
    def key(self) -> str:
        return self.name if self.kind == "NODE" else f"{self.name}__{self.from_table}__{self.to_table}"

    def meta(self) -> dict:
        out = {"table": self.name, "kind": self.kind, "columns": [list(c) for c in self.columns], "rows": self.frame.height}
        if self.kind == "REL":
            out.update({"from": self.from_table, "to": self.to_table})
        return out


@dataclass
class ParticipantDump:
    participant: str
    bank: dict  # the source bank: mode, embed_model
    manifest: dict  # the participant's manifest entry (counts, videos, inferred knowledge, indexes)
    migrations: dict[str, str]  # schema file -> checksum
    tables: list[DumpedTable] = field(default_factory=list)
    exported_at: str = ""

    def header(self) -> dict:
        return {FORMAT_KEY: FORMAT_VERSION, "participant": self.participant, "exported_at": self.exported_at,
                "bank": self.bank, "manifest": self.manifest, "migrations": self.migrations}

    def nodes(self) -> list[DumpedTable]:
        return [t for t in self.tables if t.kind == "NODE"]

    def rels(self) -> list[DumpedTable]:
        return [t for t in self.tables if t.kind == "REL"]


# -- out of a bank -----------------------------------------------------------------------------------


def dump_participant(bank: Bank, participant: str) -> ParticipantDump:
    """Read every table of one participant's database (checked against the manifest first). The
    manifest entry travels without what belongs to this bank's copy of the file (its hash)."""
    data = bank.manifest()
    with bank.open(participant) as store:
        catalog = store.catalog()
        migrations = store.migration_checksums()
        nodes = store.run("_export_nodes", participant=participant)
        rels = store.run("_export_rels", participant=participant)
    dump = ParticipantDump(participant, {"mode": data["mode"], "embed_model": data["embed_model"]},
                           {k: v for k, v in data["participants"][participant].items() if k not in BANK_LOCAL}, migrations,
                           exported_at=datetime.now(timezone.utc).isoformat(timespec="seconds"))
    nodes = nodes.unnest("node") if nodes.height else nodes
    for name, info in catalog.items():
        if info["kind"] != "NODE":
            continue
        cols = info["columns"]
        rows = nodes.filter(pl.col("tbl") == name) if nodes.height else pl.DataFrame()
        frame = (rows.select([pl.col(c).cast(polars_type(t)) for c, t in cols]) if rows.height
                 else pl.DataFrame(schema={c: polars_type(t) for c, t in cols}))
        dump.tables.append(DumpedTable(name, "NODE", list(cols), frame))
    rels = rels.unnest("rel") if rels.height else rels
    for name, info in catalog.items():
        if info["kind"] != "REL":
            continue
        cols = [("from", "STRING"), ("to", "STRING"), *info["columns"]]
        for src, dst in info["pairs"]:
            rows = (rels.filter((pl.col("tbl") == name) & (pl.col("from_tbl") == src) & (pl.col("to_tbl") == dst))
                    if rels.height else pl.DataFrame())
            if rows.height:
                frame = rows.select(pl.col("from_id").alias("from"), pl.col("to_id").alias("to"),
                                    *[pl.col(c).cast(polars_type(t)) for c, t in info["columns"]])
                # parallel edges (SPATIAL) in the order of their properties: the same database
                # content gives the same export, whatever order its rows were stored in
                frame = frame.sort([c for c, dt in frame.schema.items() if not dt.is_nested()], maintain_order=True)
            else:
                frame = pl.DataFrame(schema={c: polars_type(t) for c, t in cols})
            dump.tables.append(DumpedTable(name, "REL", cols, frame, src, dst))
    return dump


# -- JSON ----------------------------------------------------------------------------------------------


def _vectors(s: pl.Series) -> list:
    """float32 vectors as the shortest decimals that read back as the same float32 (about half
    the size of their float64 expansion, and exact)."""
    if s.null_count() == 0:
        return [[float(str(v)) for v in row] for row in s.to_numpy()]
    return [None if v is None else [float(str(x)) for x in np.asarray(v, dtype=np.float32)] for v in s.to_list()]


def _json_rows(t: DumpedTable) -> list[list]:
    frame = t.frame
    arrays = {c: _vectors(frame[c]) for c, dt in frame.schema.items() if isinstance(dt, pl.Array)}
    times = [c for c, dt in frame.schema.items() if isinstance(dt, pl.Datetime)]
    if times:
        frame = frame.with_columns([pl.col(c).dt.strftime("%Y-%m-%dT%H:%M:%S%.6f") for c in times])
    order = frame.columns
    rows = frame.drop(list(arrays)).rows(named=True) if arrays else None
    if rows is None:
        return [list(r) for r in frame.rows()]
    return [[arrays[c][i] if c in arrays else r[c] for c in order] for i, r in enumerate(rows)]


def write_json(dump: ParticipantDump, out: Path) -> Path:
    """One JSON document: the header, then the tables, one row per line (valid JSON, and
    readable with `grep`). Written to a temporary file and renamed: never half-written."""
    tmp = out.with_name(f".{out.name}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write("{\n")
            for k, v in dump.header().items():
                fh.write(f"  {json.dumps(k)}: {json.dumps(v, sort_keys=True, ensure_ascii=False)},\n")
            fh.write('  "tables": [')
            for i, t in enumerate(dump.tables):
                meta = json.dumps(t.meta(), ensure_ascii=False)[:-1]
                fh.write(("," if i else "") + f"\n    {meta}, \"data\": [")
                fh.write(",".join("\n      " + json.dumps(r, ensure_ascii=False) for r in _json_rows(t)))
                fh.write("\n    ]}")
            fh.write("\n  ]\n}\n")
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out


def _headed_dump(doc, path: Path) -> ParticipantDump:
    """The dump an export's header describes (checked), with no tables yet."""
    _check_header(doc, path)
    return ParticipantDump(doc["participant"], doc["bank"], doc["manifest"], doc["migrations"],
                           exported_at=doc.get("exported_at", ""))


def _check_header(doc, where: Path) -> None:
    if not isinstance(doc, dict) or FORMAT_KEY not in doc:
        raise DataError(f"{where}: not a memora export (no '{FORMAT_KEY}' field); make one with `memora export`")
    if doc[FORMAT_KEY] != FORMAT_VERSION:
        raise DataError(f"{where}: memora export format {doc[FORMAT_KEY]!r}; this version reads format {FORMAT_VERSION}")
    for k in ("participant", "bank", "manifest", "migrations", "tables"):
        if k not in doc:
            raise DataError(f"{where}: damaged memora export: no '{k}' field")
    for k, kind in (("bank", dict), ("manifest", dict), ("migrations", dict), ("tables", list)):
        if not isinstance(doc[k], kind):
            raise DataError(f"{where}: damaged memora export: field '{k}' is a {type(doc[k]).__name__}, not a "
                            f"{'map' if kind is dict else 'list'}")
    for k in ("mode", "embed_model"):
        if not isinstance(doc["bank"].get(k), str):
            raise DataError(f"{where}: damaged memora export: no 'bank.{k}' text field")
    p = doc["participant"]
    if not is_participant_id(p):
        raise DataError(f"{where}: field 'participant' is {json.dumps(p)[:40]}, not a participant id ({RULE})")
    counts = doc["manifest"].get("counts")
    if not isinstance(counts, dict):
        raise DataError(f"{where}: damaged memora export: field 'manifest.counts' is not a map of record counts")
    for k, v in counts.items():
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise DataError(f"{where}: field 'manifest.counts.{k}' is {json.dumps(v)[:40]}, not a whole number")


def _table_from_meta(meta: dict, where: Path) -> tuple[str, str, list[tuple[str, str]], str, str]:
    try:
        kind = meta["kind"]
        cols = [(str(c), str(t)) for c, t in meta["columns"]]
        name = meta["table"]
        src, dst = (meta["from"], meta["to"]) if kind == "REL" else ("", "")
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"{where}: damaged memora export: a table entry lacks {exc}") from exc
    if kind not in ("NODE", "REL"):
        raise DataError(f"{where}: damaged memora export: table {name} has kind {kind!r}")
    return name, kind, cols, src, dst


def _frame(rows: list, cols: list[tuple[str, str]], where: str) -> pl.DataFrame:
    schema = {c: polars_type(t) for c, t in cols}
    fixed = {j: (c, dt.size) for j, (c, dt) in enumerate(schema.items()) if isinstance(dt, pl.Array)}
    for i, r in enumerate(rows):
        if not isinstance(r, list) or len(r) != len(cols):
            raise DataError(f"{where}: row {i + 1} has {len(r) if isinstance(r, list) else 'no'} values, "
                            f"the table has {len(cols)} columns")
        for j, (c, size) in fixed.items():  # polars panics on an array of the wrong length
            if r[j] is not None and (not isinstance(r[j], list) or len(r[j]) != size):
                got = f"{len(r[j])} values" if isinstance(r[j], list) else f"a {type(r[j]).__name__}"
                raise DataError(f"{where}: row {i + 1}, column {c}: {got}, not {size} (an embedding of another "
                                "model?)")
    times = {j for j, (_, t) in enumerate(cols) if t == "TIMESTAMP"}
    if times:
        try:
            rows = [[datetime.fromisoformat(v) if j in times and isinstance(v, str) else v for j, v in enumerate(r)]
                    for r in rows]
        except ValueError as exc:
            raise DataError(f"{where}: a date/time value does not parse ({exc})") from exc
    try:
        return pl.DataFrame(rows, schema=schema, orient="row", strict=False)
    except (Exception, pl.exceptions.PanicException) as exc:  # noqa: BLE001 - polars raises several kinds (and
        # panics, a BaseException); all mean a value of the wrong type
        raise DataError(f"{where}: values do not fit the column types ({exc})") from exc


def read_json(path: Path) -> ParticipantDump:
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not a memora export (not text: {exc.reason})") from exc
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: not a memora export (not JSON: {exc})") from exc
    except RecursionError:
        raise DataError(f"{path}: not a memora export (JSON nested too deep to read)") from None
    dump = _headed_dump(doc, path)
    for meta in doc["tables"]:
        name, kind, cols, src, dst = _table_from_meta(meta, path)
        rows = meta.get("data")
        if not isinstance(rows, list):
            raise DataError(f"{path}: damaged memora export: table {name} has no 'data' list")
        where = f"{path}: table {name}" + (f" ({src} -> {dst})" if kind == "REL" else "")
        dump.tables.append(DumpedTable(name, kind, cols, _frame(rows, cols, where), src, dst))
    return dump


# -- Parquet ---------------------------------------------------------------------------------------------


def write_parquet(dump: ParticipantDump, out: Path) -> Path:
    """A directory: one Parquet file per table (relationship tables per FROM/TO pair) and
    export.json, the header with every table's columns and file. Built in a temporary directory
    and renamed into place."""
    tmp = out.with_name(f".{out.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir(parents=True)
        tables = []
        for t in dump.tables:
            name = f"{t.key}.parquet"
            t.frame.write_parquet(tmp / name)
            tables.append({**t.meta(), "file": name})
        (tmp / PARQUET_META).write_text(json.dumps({**dump.header(), "tables": tables}, indent=2, sort_keys=True,
                                                   ensure_ascii=False))
        if out.is_dir():  # replacing an earlier export (--force)
            shutil.rmtree(out)
        elif out.exists():
            out.unlink()
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def read_parquet(folder: Path) -> ParticipantDump:
    meta_path = folder / PARQUET_META
    if not meta_path.is_file():
        raise DataError(f"{folder}: not a memora export (a Parquet export is a directory with {PARQUET_META})")
    try:
        doc = json.loads(meta_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{meta_path}: not a memora export (not JSON: {exc})") from exc
    except RecursionError:
        raise DataError(f"{meta_path}: not a memora export (JSON nested too deep to read)") from None
    dump = _headed_dump(doc, meta_path)
    for meta in doc["tables"]:
        name, kind, cols, src, dst = _table_from_meta(meta, meta_path)
        file = folder / str(meta.get("file", ""))
        if not meta.get("file") or not file.is_file() or file.parent != folder:
            raise DataError(f"{meta_path}: table {name}: its file {meta.get('file')!r} is missing")
        try:
            frame = pl.read_parquet(file)
        except Exception as exc:  # noqa: BLE001 - any read failure means a damaged file
            raise DataError(f"{file}: not a readable Parquet file ({exc})") from exc
        want = {c: polars_type(t) for c, t in cols}
        if dict(frame.schema) != want:
            raise DataError(f"{file}: columns {dict(frame.schema)} do not match the export's {want}")
        dump.tables.append(DumpedTable(name, kind, cols, frame, src, dst))
    return dump


def read_dump(path: str | Path) -> ParticipantDump:
    """Read an export: a JSON file, or a Parquet export directory."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file or directory")
    return read_parquet(path) if path.is_dir() else read_json(path)

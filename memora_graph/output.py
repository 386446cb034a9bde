"""One renderer for every reading command: table, csv, json or ndjson of a polars frame."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import polars as pl

FORMATS = ("table", "csv", "json", "nl")


ROWS_JSON = "A JSON array of objects, one per row."


def _jsonable(df: pl.DataFrame) -> list[dict]:
    import polars as pl  # here, not at import time: `memora --help` loads this module

    drop = [c for c, t in df.schema.items() if isinstance(t, pl.Array)]  # embeddings: not for humans
    return df.drop(drop).to_dicts()


def _flat(df: pl.DataFrame) -> pl.DataFrame:
    """CSV has no nested values: lists become '; '-joined text, structs JSON, embeddings are dropped."""
    import polars as pl

    cols = []
    for c, t in df.schema.items():
        if isinstance(t, pl.Array):
            continue
        if isinstance(t, pl.List):
            cols.append(pl.col(c).list.eval(pl.element().cast(pl.String)).list.join("; ").alias(c))
        elif isinstance(t, pl.Struct):
            cols.append(pl.col(c).struct.json_encode().alias(c))
        else:
            cols.append(pl.col(c))
    return df.select(cols)


def render(df: pl.DataFrame, fmt: str = "table") -> str:
    if fmt == "csv":
        return _flat(df).write_csv()
    if fmt == "json":
        return json.dumps(_jsonable(df), indent=2, default=str)
    if fmt == "nl":
        return "\n".join(json.dumps(r, default=str) for r in _jsonable(df))
    if df.is_empty():
        return "(no rows)"
    import io

    from rich.console import Console
    from rich.table import Table

    rows = _jsonable(df)
    table = Table(show_lines=False)
    for c in rows[0]:
        table.add_column(c, overflow="fold")
    for row in rows:
        table.add_row(*["" if v is None else str(v) for v in row.values()])
    buf = io.StringIO()
    Console(width=200, file=buf).print(table)
    return buf.getvalue().rstrip()

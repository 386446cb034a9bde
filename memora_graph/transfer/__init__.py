"""Move one participant's memory between banks and into other tools: `memora export` writes it
as JSON (every table, embeddings included; `memora import` loads it back), Parquet (one file per
table) or GraphML (for Gephi or networkx); `memora import` loads a JSON or Parquet export into a
bank as a new participant."""

from __future__ import annotations

from pathlib import Path

from memora_graph.bank import Bank
from memora_graph.errors import DataError
from memora_graph.transfer.dump import ParticipantDump, dump_participant, read_dump, write_json, write_parquet
from memora_graph.transfer.graphml import to_graph, write_graphml
from memora_graph.transfer.load import ImportResult, import_participant

FORMATS = {"json": ".json", "graphml": ".graphml", "parquet": ".parquet"}


def default_output(participant: str, fmt: str) -> Path:
    return Path(f"{participant}{FORMATS[fmt]}")


def export_participant(bank_path: str | Path, participant: str, fmt: str = "json", out: str | Path | None = None,
                       embeddings: bool = False, force: bool = False) -> tuple[Path, ParticipantDump]:
    """Write one participant's memory as `fmt` to `out` (default `P01.json`, `P01.graphml`,
    `P01.parquet/`). Embeddings are always in JSON and Parquet (an import needs them), in GraphML
    only with `embeddings`. An existing output is replaced only with `force`."""
    if fmt not in FORMATS:
        raise DataError(f"no export format {fmt!r}; formats: {', '.join(FORMATS)}")
    out = Path(out) if out else default_output(participant, fmt)
    if out.exists() and not force:
        raise DataError(f"{out}: exists; pass --force to replace it, or choose another --out")
    if fmt != "parquet" and out.is_dir():
        raise DataError(f"{out}: is a directory; a {fmt} export is one file")
    out.parent.mkdir(parents=True, exist_ok=True)
    dump = dump_participant(Bank(bank_path), participant)
    if fmt == "json":
        write_json(dump, out)
    elif fmt == "parquet":
        write_parquet(dump, out)
    else:
        write_graphml(dump, out, embeddings=embeddings)
    return out, dump


__all__ = ["FORMATS", "ImportResult", "ParticipantDump", "default_output", "dump_participant", "export_participant",
           "import_participant", "read_dump", "to_graph", "write_graphml"]

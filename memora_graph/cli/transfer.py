"""`memora export` and `memora import`: one participant's memory out of a bank and into another."""

from __future__ import annotations

import click
import polars as pl

from memora_graph.output import render


@click.command("export")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--participant", required=True, help="Whose memory to export (P01).")
@click.option("--format", "fmt", type=click.Choice(["json", "graphml", "parquet"]), default="json", show_default=True,
              help="json: every table, embeddings included (`memora import` reads it); parquet: a directory, one file "
                   "per table (also importable); graphml: a graph for Gephi or networkx.")
@click.option("--out", type=click.Path(), help="Where to write (default: P01.json, P01.graphml or the directory P01.parquet).")
@click.option("--embeddings", is_flag=True, help="GraphML only: also write each node's embedding (a JSON list).")
@click.option("--force", is_flag=True, help="Replace --out if it exists.")
def export_cmd(bank, participant, fmt, out, embeddings, force):
    """Export one participant's memory: every node and relationship, with its ids and properties.

    A JSON or Parquet export is a whole memory (with the manifest entry and the embeddings):
    `memora import` loads it into another bank with the same counts, ids and tool results.
    GraphML is for looking at it elsewhere (Gephi, networkx.read_graphml); lists are JSON strings.

    \b
    Examples:
      memora export banks/epic --participant P01                      # P01.json
      memora export banks/epic --participant P01 --format graphml --out p01.graphml
      memora export banks/epic --participant P01 --format parquet --out exports/P01
      memora import banks/other P01.json
    """
    from rich.console import Console

    from memora_graph.transfer import export_participant

    if embeddings and fmt != "graphml":
        raise click.UsageError("--embeddings applies to --format graphml (JSON and Parquet always have them)")
    with Console(stderr=True).status(f"exporting {participant} from {bank} as {fmt}"):
        path, dump = export_participant(bank, participant, fmt, out, embeddings=embeddings, force=force)
    nodes = sum(t.frame.height for t in dump.nodes())
    rels = sum(t.frame.height for t in dump.rels())
    click.echo(f"{participant}: {nodes} nodes and {rels} relationships in {len(dump.tables)} tables -> {path}")


@click.command("import")
@click.argument("bank", type=click.Path(file_okay=False))
@click.argument("file", type=click.Path(exists=True))
def import_cmd(bank, file):
    """Import a JSON or Parquet export (`memora export`) into BANK as a new participant.

    BANK is created if it does not exist. The database is built aside, checked against the
    counts the export recorded, and only then added to the bank, so a refused or failed
    import writes nothing. Refused when BANK already holds the participant, when its mode or
    embedding model differ from the export's, or when FILE is not a memora export.

    \b
    Examples:
      memora export banks/epic --participant P01 --out P01.json
      memora import banks/copy P01.json
      memora stats banks/copy --participant P01
      memora import banks/copy exports/P02                        # a Parquet export directory
    """
    from rich.console import Console

    from memora_graph.transfer import import_participant

    with Console(stderr=True).status(f"importing {file} into {bank}"):
        res = import_participant(bank, file)
    click.echo(render(pl.DataFrame([{"participant": res.participant, **res.counts}])))
    click.echo(f"imported {res.participant} into {res.db} in {res.seconds:.1f} s"
               + (f" (indexes: {', '.join(res.indexes)})" if res.indexes else ""))

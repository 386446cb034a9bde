"""`memora bench ...`: generate a MEMORA-Bench suite from annotations, validate a release folder."""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

from memora_graph.errors import MemoraError

bench_group = click.Group(
    "bench",
    help="MEMORA-Bench: generate EAM-QA and Planning tasks from action annotations, and validate "
    "release folders (the bundled calibration cohort, a full release, or a generated suite).",
)


def _participants(value: str | None) -> list[str] | None:
    if not value or value.strip().lower() == "all":
        return None
    return [p.strip().upper() for p in value.split(",") if p.strip()]


@bench_group.command("generate")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write the release layout into (created if missing; files are overwritten).")
@click.option("--participants", default="all", show_default=True,
              help="Comma-separated participant ids (P01,P02) or 'all'.")
@click.option("--seed", default=42, show_default=True, type=int, help="Seed for every random choice.")
@click.option("--annotations", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="EPIC-style annotation CSV (default: the bundled extension subset).")
@click.option("--no-dedup", is_flag=True, help="Skip the embedding near-duplicate check (exact dedup still applies).")
@click.option("--bank", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="A memory bank whose object registry grounds Replay nouns (enriched_narration, matched_object).")
def generate_cmd(out: Path, participants: str, seed: int, annotations: Path | None, no_dedup: bool,
                 bank: Path | None) -> None:
    """Generate EAM-QA questions and Planning Replay/Generalize tasks from annotations.

    Writes eam_qa/questions/pXX.json and planning/suites/{replay,generalize}/pXX.json (the
    official layout), planning/audit/replay_filtered/ (tasks above the repeat-rate limit) and
    generation.json, then prints the counts table. No LLM is used; E-correct controls draw
    donor questions from every participant in the annotations.

    \b
    Examples:
      memora bench generate --out runs/bench
      memora bench generate --out runs/bench-p01 --participants P01,P02 --seed 7
      memora bench generate --out runs/bench --annotations EPIC_100_train_subset.csv
      memora bench generate --out runs/bench --bank banks/epic
    """
    from memora_graph.bench.generate import generate_suite, write_generated
    from memora_graph.bench.validate import ValidationReport, check_suite, count_suite, render_table

    try:
        frame = None
        if annotations is not None:
            from memora_graph.perceive.annotations import load_annotations

            frame = load_annotations(annotations)
        registries = None
        if bank is not None:
            from memora_graph.bank import Bank

            registries = Bank(bank).object_registries(_participants(participants))
        suite, report = generate_suite(frame, _participants(participants), seed=seed, registries=registries,
                                       embedder=None if no_dedup else "default")
        t0 = time.perf_counter()
        write_generated(suite, report, out)
        seconds = report.seconds + time.perf_counter() - t0
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    table = ValidationReport(str(out), count_suite(suite), check_suite(suite))
    click.echo(render_table(table))
    click.echo(f"\nWrote {out} in {seconds:.1f} s (seed {seed}; near-duplicate check: {report.semantic_dedup}).")


@bench_group.command("validate")
@click.argument("directory", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--participants", default="all", show_default=True,
              help="Comma-separated participant ids (P01,P02) or 'all'.")
@click.option("--json", "as_json", is_flag=True, help="Print the counts and problems as JSON.")
def validate_cmd(directory: Path, participants: str, as_json: bool) -> None:
    """Check every task file of a release folder and print counts per participant and type.

    Every item is validated (a malformed one is reported with its file, index, id and field),
    metadata counts are checked against the items, and the table gives answerable vs E-correct
    questions per type, Replay tasks (and steps) and Generalize tasks per participant. Exits 1
    when a problem is found.

    \b
    Examples:
      memora bench validate bench/data/memora-bench-calibration
      memora bench validate runs/bench --participants P01,P02
      memora bench validate runs/bench --json
    """
    from memora_graph.bench.validate import render_table, validate_suite

    try:
        report = validate_suite(directory, _participants(participants))
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    if as_json:
        click.echo(json.dumps(report.as_dict(), indent=2))
    else:
        click.echo(render_table(report))
    if report.problems:
        raise click.ClickException(f"{len(report.problems)} problem(s) in {directory}")

"""`memora perf verify`: what checking a database before opening it costs, against a one-shot command."""

from __future__ import annotations

import os

import click

from memora_graph.output import render


@click.command("verify")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--participant", required=True, help="Whose database to open (P04).")
@click.option("--repeat", default=5, show_default=True, help="Runs of each measurement (medians are printed).")
@click.option("--query", "text", default="bowl", show_default=True, help="What the one-shot command searches for.")
def perf_verify_cmd(bank, participant, repeat, text):
    """What checking a database before opening it costs, against a one-shot command.

    In this process: sha256 of the file (hashed afresh each run), and opening + closing the
    participant with and without the checks. Then `memora tool BANK search_objects QUERY
    --participant P` as a new process, with and without --no-verify (model load included, as a
    user runs it). Prints medians and the checks' share of the one-shot command.

    \b
    Example:
      memora perf verify banks/epic --participant P04
    """
    import statistics
    import subprocess
    import sys
    import time

    import polars as pl

    from memora_graph.bank import Bank
    from memora_graph import files

    b = Bank(bank)
    db = b.db_path(participant)

    def timed(fn) -> float:
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0

    def fresh_hash():
        files.forget_hashes()
        files.file_sha256(db)

    def open_first():  # as the first open after a write: the file is hashed
        files.forget_hashes()
        b.forget_seen(participant)
        b.open(participant).close()

    def open_again():  # unchanged since a checked open: BANK/.verified.json spares the hash
        files.forget_hashes()
        b.open(participant).close()

    first, again, plain = "open + close, checked (hashed)", "open + close, checked (unchanged: cached)", \
        "open + close, --no-verify"
    runs = {"sha256 of the database file": [timed(fresh_hash) for _ in range(repeat)], first: [], again: [], plain: []}
    for _ in range(repeat):
        runs[first].append(timed(open_first))
        runs[again].append(timed(open_again))
        runs[plain].append(timed(lambda: b.open(participant, verify=False).close()))
    cmd = [sys.executable, "-m", "memora_graph.cli", "tool", str(bank), "search_objects", text, "--participant",
           participant, "--json"]
    runs["one-shot `memora tool ... search_objects`"] = []
    runs["one-shot, --no-verify"] = []
    for _ in range(repeat):
        for key, extra in (("one-shot `memora tool ... search_objects`", []), ("one-shot, --no-verify", ["--no-verify"])):
            t0 = time.perf_counter()
            subprocess.run(cmd + extra, capture_output=True, check=True)
            runs[key].append(time.perf_counter() - t0)
    med = {k: statistics.median(v) for k, v in runs.items()}
    size = db.stat().st_size
    click.echo(render(pl.DataFrame([{"measure": k, "median_s": round(v, 4), "runs": len(runs[k])}
                                    for k, v in med.items()])))
    one_shot = med["one-shot `memora tool ... search_objects`"]
    click.echo(f"{participant}.kuzu: {size / 1e6:.1f} MB; sha256 at {size / 1e6 / med['sha256 of the database file']:.0f} MB/s")
    for label, key in (("hashing", first), ("unchanged file", again)):
        added = med[key] - med[plain]
        click.echo(f"the checks add {added * 1000:.0f} ms to an open ({label}): {100 * added / one_shot:.1f}% of the "
                   f"one-shot command ({one_shot:.2f} s; with --no-verify {med['one-shot, --no-verify']:.2f} s)")
    load = os.getloadavg()
    click.echo(f"machine: load average {load[0]:.2f} (1 min), {load[1]:.2f} (5 min), {os.cpu_count()} CPUs")

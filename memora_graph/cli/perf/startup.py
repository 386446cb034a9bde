"""`memora perf startup`: how fast one-shot commands start, each run a new process."""

from __future__ import annotations

import os
import resource
import shutil
import statistics
import subprocess
import sys
import time

import click

from memora_graph.cli.options import check_participant_option


def _run(cmd: list[str], env: dict | None = None) -> tuple[float, float, str]:
    """(wall seconds, CPU seconds of the child, stdout) of one run of `cmd` as a new process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode != 0:
        raise click.ClickException(f"{' '.join(cmd)} failed ({res.returncode}): {res.stderr.strip()[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, res.stdout


@click.command("startup")
@click.argument("bank", type=click.Path(exists=True, file_okay=False), default="banks/epic")
@click.option("--participant", default="P04", show_default=True, callback=check_participant_option,
              help="Whose memory the one-shot tool reads.")
@click.option("--tool", "tool_name", default="search_objects", show_default=True, help="The tool of the one-shot call.")
@click.option("--query", "text", default="bowl", show_default=True, help="Its query.")
@click.option("--repeat", default=7, show_default=True, type=click.IntRange(min=1), help="Runs of each (medians are printed).")
def perf_startup_cmd(bank, participant, tool_name, text, repeat):
    """How fast one-shot commands start: `memora --help` and a one-shot `memora tool` as new
    processes (median wall and CPU seconds of several runs).

    The tool runs three ways: as a user runs it (the stores persisted next to the bank, see
    memora_graph/retrieve/persist.py); with them removed for the run, so that each call reads
    Kùzu and writes them again (an old bank's first call); and reading Kùzu without them
    (MEMORA_TOOL_STORES=0). Each run checks the result is the same as the first. Also prints the
    import of torch, polars and kuzu in `memora --help` (none expected).

    \b
    Example:
      memora perf startup banks/epic --participant P04
    """
    from memora_graph.retrieve.persist import store_dir

    exe = [sys.executable, "-m", "memora_graph.cli"]
    tool = [*exe, "tool", str(bank), tool_name, text, "--participant", participant, "--json"]
    load_before = os.getloadavg()
    rows: list[tuple[str, list[float], list[float]]] = []

    def measure(label: str, cmd: list[str], prepare=None, env=None, expect: str | None = None) -> str:
        walls, cpus, out = [], [], None
        for _ in range(repeat):
            if prepare is not None:
                prepare()
            wall, cpu, got = _run(cmd, env)
            if expect is not None and got != expect:
                raise click.ClickException(f"{label}: the result differs from the one read through Kùzu")
            out = got if out is None else out
            walls.append(wall)
            cpus.append(cpu)
        rows.append((label, walls, cpus))
        return out

    measure("memora --help", [*exe, "--help"])
    stores = store_dir(bank, participant)
    plain_env = {**os.environ, "MEMORA_TOOL_STORES": "0"}
    reference = measure(f"memora tool ... {tool_name} (no persisted stores: Kùzu)", tool, env=plain_env)
    measure(f"memora tool ... {tool_name} (first call: computes and writes them)", tool,
            prepare=lambda: shutil.rmtree(stores, ignore_errors=True), expect=reference)
    measure(f"memora tool ... {tool_name} (persisted stores)", tool, expect=reference)
    probe = _run([sys.executable, "-c", "import sys; sys.argv = ['memora', '--help']\n"
                  "from memora_graph.cli import main\ntry:\n    main()\nexcept SystemExit:\n    pass\n"
                  "print(' '.join(sorted({m.split('.')[0] for m in sys.modules} & "
                  "{'torch', 'polars', 'kuzu', 'numpy', 'pydantic', 'onnxruntime'})) or 'none')"])[2]
    click.echo(f"{'command':<72} {'median wall s':>13} {'median CPU s':>12} {'runs':>5}")
    for label, walls, cpus in rows:
        click.echo(f"{label:<72} {statistics.median(walls):>13.3f} {statistics.median(cpus):>12.3f} {len(walls):>5}")
    click.echo(f"heavy modules imported by `memora --help`: {probe.strip().splitlines()[-1]}")
    click.echo(f"targets: --help <= 0.3 s wall, one-shot tool <= 1.5 s wall; machine: load average "
               f"{load_before[0]:.2f} before, {os.getloadavg()[0]:.2f} after ({os.cpu_count()} CPUs): where wall "
               "exceeds CPU by much, the machine was shared")

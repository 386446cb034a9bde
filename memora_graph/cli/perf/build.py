"""`memora perf build`: build the bundled annotations from scratch and print where the time went,
phase by phase, with how busy the machine was meanwhile (`OtherCPU`)."""

from __future__ import annotations

import os
import resource
import tempfile

import click
import polars as pl

from memora_graph.cli.options import participants_option
from memora_graph.output import render


@click.command("build")
@click.option("--bank", "bank_dir", type=click.Path(file_okay=False), help="Where to build (default: a temporary directory).")
@participants_option()
@click.option("--episodic", is_flag=True, help="Time the MEMORA-Episodic build (no consolidation).")
@click.option("--fts", is_flag=True, help="Time the build with the full-text indexes (`memora build --fts`).")
@click.option("--jobs", type=click.IntRange(min=1), default=None, help="Worker processes (default: as `memora build`).")
def perf_build(bank_dir, participants, episodic, fts, jobs):
    """Build the bundled annotations from scratch and print where the time went: every phase,
    summing to the wall time (to worker-seconds with --jobs > 1), and the share of graph work
    (all but embedding and model load).

    \b
    Example:
      memora perf build
    """
    from memora_graph.pipeline import build_bank

    pids = participants
    load_before = os.getloadavg()
    others = OtherCPU()
    with tempfile.TemporaryDirectory() as tmp:
        res = build_bank(bank_dir or f"{tmp}/bank", pids, episodic=episodic, fts=fts, jobs=jobs)
    others_s = others.seconds()
    total = res.wall_seconds
    phases = res.phases()
    capacity = res.jobs * total  # seconds the phases add up to: the wall time, or worker-seconds
    rows = [{"phase": k, "seconds": round(v, 2), "share%": round(100 * v / capacity, 1) if capacity else 0.0}
            for k, v in phases.items()]
    rows.append({"phase": "sum of phases", "seconds": round(sum(phases.values()), 2),
                 "share%": round(100 * sum(phases.values()) / capacity, 1) if capacity else 0.0})
    click.echo(render(pl.DataFrame(rows)))
    if res.jobs > 1:
        click.echo(f"{res.jobs} worker processes: the phases are worker-seconds, summing to {res.jobs} x wall")
    click.echo(f"participants {len(res.participants)}  segments {res.segments}  wall {total:.1f} s  "
               f"segments/s {res.segments / total:.0f}  texts encoded {res.texts_encoded}  encode calls by torch "
               f"threads {dict(sorted(res.embed_threads.items()))}")
    click.echo(f"machine: load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}"
               + (f"; during the build other processes used {others_s[0]:.1f} CPU-seconds and the hypervisor took "
                  f"{others_s[1]:.1f} (steal)" if others_s is not None else ""))
    of = "wall" if res.jobs == 1 else f"the workers' busy {res.busy_seconds:.1f} s"
    click.echo(f"graph work (all but embedding {res.embedding_seconds:.1f} s and model load {res.model_seconds:.1f} s): "
               f"{res.graph_seconds:.1f} s = {100 * res.graph_share:.0f}% of {of} (target <= 25%; wall {total:.1f} s, "
               f"target <= 120 s)")


class OtherCPU:
    """CPU seconds other processes used while this one ran (Linux /proc/stat busy time minus our
    own) and the hypervisor took from this virtual machine (steal), to tell a clean timing from
    one taken on a shared machine."""

    def __init__(self):
        self._start = self._sample()

    @staticmethod
    def _sample() -> tuple[float, float, float] | None:
        try:
            with open("/proc/stat") as fh:
                f = [int(x) for x in fh.readline().split()[1:9]] + [0]
        except (OSError, ValueError):
            return None
        me = resource.getrusage(resource.RUSAGE_SELF)
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)
        own = me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime
        tick = os.sysconf("SC_CLK_TCK")
        return (f[0] + f[1] + f[2] + f[5] + f[6]) / tick, own, f[7] / tick

    def seconds(self) -> tuple[float, float] | None:
        """(other processes' CPU-seconds, steal seconds) since construction."""
        end = self._sample()
        if self._start is None or end is None:
            return None
        return max((end[0] - self._start[0]) - (end[1] - self._start[1]), 0.0), end[2] - self._start[2]

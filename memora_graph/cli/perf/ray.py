"""`memora perf ray`: the Ray executor's overhead against the local executor, side by side.

Builds the bundled annotations from scratch with each executor in turn, alternating which goes
first, `--repeat` times, and prints each pair's wall times, the ratio, and how busy the machine
was meanwhile (load average, CPU-seconds the whole machine was busy, steal), since on a shared
machine only side-by-side ratios mean anything. The Ray instance is started once, before the
pairs, and timed on its own: `memora build --executor ray` without `--ray-address` pays it once
per command, a cluster pays it once.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time

import click


def _machine() -> tuple[float, float] | None:
    """(CPU-seconds the machine's cores were busy, steal seconds) so far, from /proc/stat."""
    try:
        with open("/proc/stat") as fh:
            f = [int(x) for x in fh.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    tick = os.sysconf("SC_CLK_TCK")
    return (f[0] + f[1] + f[2] + f[5] + f[6]) / tick, f[7] / tick


def _timed(build) -> dict:
    before, load = _machine(), os.getloadavg()[0]
    t0 = time.perf_counter()
    res = build()
    wall = time.perf_counter() - t0
    after = _machine()
    busy = (after[0] - before[0], after[1] - before[1]) if before and after else (None, None)
    return {"wall": wall, "segments": res.segments, "participants": len(res.participants), "load": load,
            "busy_cpu_s": busy[0], "steal_s": busy[1]}


@click.command("ray")
@click.option("--participants", default="all", show_default=True)
@click.option("--repeat", type=click.IntRange(min=1), default=2, show_default=True,
              help="Pairs of builds (local and Ray, alternating which goes first).")
@click.option("--ray-address", default=None, help="A running cluster to use (default: a local Ray instance).")
def perf_ray(participants, repeat, ray_address):
    """Ray's overhead against the local executor on a full build, measured side by side.

    \b
    Example:
      memora perf ray                      # all 18 participants, 2 pairs (~6 min on 2 idle cores)
    """
    import polars as pl

    from memora_graph.bank import parse_participants
    from memora_graph.executors import cpu_count, make_executor
    from memora_graph.executors.tasks import cluster
    from memora_graph.output import render
    from memora_graph.pipeline import build_bank

    pids = parse_participants(participants)
    ex = make_executor("ray", ray_address)
    rows = []
    t0 = time.perf_counter()
    with cluster(ex) as ray:
        started = time.perf_counter() - t0
        cpus = int(ray.cluster_resources().get("CPU", 0))
        for i in range(repeat):
            order = ("local", "ray") if i % 2 == 0 else ("ray", "local")
            pair = {}
            for name in order:
                with tempfile.TemporaryDirectory() as tmp:
                    pair[name] = _timed(lambda: build_bank(f"{tmp}/bank", pids, executor=ex if name == "ray" else None))
                click.echo(f"pair {i + 1} {name}: {pair[name]['wall']:.1f} s (load average {pair[name]['load']:.2f})",
                           err=True)
            for name in order:
                r = pair[name]
                rows.append({"pair": i + 1, "executor": name, "first": name == order[0], "wall_s": round(r["wall"], 1),
                             "ray/local": round(pair["ray"]["wall"] / pair["local"]["wall"], 3),
                             "load_avg_before": round(r["load"], 2),
                             "machine_busy_cpu_s": None if r["busy_cpu_s"] is None else round(r["busy_cpu_s"], 1),
                             "steal_s": None if r["steal_s"] is None else round(r["steal_s"], 1),
                             "segments": r["segments"]})
    click.echo(render(pl.DataFrame(rows)))
    ratios = [r["ray/local"] for r in rows if r["executor"] == "ray"]
    local = statistics.median(r["wall_s"] for r in rows if r["executor"] == "local")
    med = statistics.median(ratios)
    click.echo(f"{len(pids) if pids else 'all'} participants, {rows[0]['segments']} segments; local executor: "
               f"{cpu_count()} cores, default worker processes; Ray: {cpus} CPUs, one task per participant")
    click.echo(f"Ray overhead (median of {len(ratios)} pairs): {100 * (med - 1):+.1f}% wall (target <= +15%); "
               f"starting the local Ray instance: {started:.1f} s once per command "
               f"({100 * (med - 1 + started / local):+.1f}% with it, against the median local build {local:.1f} s)")

"""The executor options every scaling command shares (`memora build`, `memora consolidate`,
`memora bench run`), and the executor they make."""

from __future__ import annotations

import click

from memora_graph.executors import DEFAULT_RETRIES, EXECUTORS, Executor, make_executor


def executor_options(f):
    """--executor, --ray-address, --retries, --ray-shared."""
    for decorator in reversed((
        click.option("--executor", type=click.Choice(EXECUTORS), default="local", show_default=True,
                     help="Where the per-participant work runs: 'local' (this machine's processes) or 'ray' (one "
                          "Ray task per participant, or per condition and participant; needs the [ray] extra)."),
        click.option("--ray-address", default=None, metavar="ADDR",
                     help="With --executor ray: the cluster to join, e.g. ray://head:10001 or auto (default: start a "
                          "local Ray instance for this command)."),
        click.option("--retries", type=click.IntRange(min=0), default=DEFAULT_RETRIES, show_default=True,
                     help="With --executor ray: how many times a failed task is tried again before its participant "
                          "is reported as failed."),
        click.option("--ray-shared", type=click.Path(file_okay=False), default=None,
                     help="With --executor ray: a directory every node and this machine see at the same path; tasks "
                          "hand finished databases back through it instead of Ray's object store."),
    )):
        f = decorator(f)
    return f


def executor_from(executor: str, ray_address: str | None, retries: int, ray_shared: str | None,
                  base_url: str | None = None) -> Executor:
    if executor == "local" and retries != DEFAULT_RETRIES:
        raise click.UsageError("--retries applies with --executor ray")
    return make_executor(executor, ray_address, retries, base_url, ray_shared)


def video_jobs(video: str, participant: str | None) -> list[tuple[str, str]]:
    """(participant, path) per Ray task: the one --participant, or each P01/, P02/ ... folder of a
    directory (that participant's videos, built in order)."""
    from pathlib import Path

    from memora_graph.bank import _PID

    path = Path(video).resolve()
    if participant:
        return [(participant, str(path))]
    folders = sorted(d for d in path.iterdir() if d.is_dir() and _PID.match(d.name)) if path.is_dir() else []
    if not folders:
        raise click.UsageError(f"{video}: give --participant, or a directory with one folder per participant "
                               "(P01/, P02/ ...) to build each as a Ray task")
    return [(d.name, str(d)) for d in folders]


def build_video_ray(bank: str, video: str, backend: str, embed_model: str | None, quiet: bool, ex: Executor,
                    opts: dict) -> None:
    """`memora build --video ... --executor ray`: one task per participant, one progress bar."""
    import polars as pl

    from memora_graph.bank import Bank, check_writable
    from memora_graph.cli_options import progress_bar
    from memora_graph.executors.build import video_on_ray
    from memora_graph.output import render
    from memora_graph.stats import decision_shares

    jobs = video_jobs(video, opts.pop("participant"))
    if opts.get("video_id") and len(jobs) > 1:
        raise click.UsageError("--video-id names one video of one participant")
    kwargs = {**opts, "backend": backend, "embed_model": embed_model}
    progress = progress_bar(quiet)
    task = progress.add_task("video clips", total=0)

    def on_event(ev: tuple) -> None:
        kind, p, v, value = ev
        if kind == "video":
            progress.update(task, total=(progress.tasks[0].total or 0) + value, description=f"{p} {v}")
        else:
            progress.update(task, advance=1)

    with progress:
        results = video_on_ray(ex, Bank(check_writable(bank)), jobs, kwargs, on_event=on_event,
                               on_notice=lambda text: click.echo(text, err=True))
    rows = []
    for res in results:
        c, shares = res.counts, decision_shares(res.decisions)
        rows.append({"participant": res.participant, "videos": len(res.videos),
                     "built": sum(not v.get("skipped") for v in res.videos), "segments": c.get("segments"),
                     "entities": c.get("entities"), "state_events": c.get("state_events"), "places": c.get("places"),
                     "NOOP%": shares["NOOP"], "UPDATE%": shares["UPDATE"], "ADD%": shares["ADD"],
                     "DELETE%": shares["DELETE"], "model_calls": len(res.calls),
                     "failed_calls": sum(not r.ok for r in res.calls), "seconds": round(res.wall_seconds, 1)})
    click.echo(render(pl.DataFrame(rows)))
    click.echo(f"bank {bank}: {len(rows)} participant(s) built from video as Ray tasks")

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

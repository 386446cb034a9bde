"""Where the per-participant work of a command runs: `local` (this machine: the process pools of
`memora build --jobs` and `memora bench run --workers`) or `ray` (tasks on a Ray cluster, or a
local Ray instance).

Builds, consolidation and evaluations split naturally: one Kùzu file per participant, one records
shard per (condition, participant). Under `ray` a task does one participant (or one shard) in the
worker's own scratch space and hands back what it made; the driver, the process that runs the
command, installs it into the bank (or the run folder) exactly as the local executor would, so
the bank and its manifest only ever change on the driver. See `executors/bundle.py` (moving a
participant's files) and `executors/tasks.py` (submitting, retrying, progress). This package knows
no work of its own: each Ray task sits beside the work it runs (`pipeline/ray.py` builds,
`consolidate/ray.py` consolidation, `bench/ray.py` evaluation shards).

Ray is an optional extra: `pip install -e '.[ray]'`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from memora_graph.errors import MemoraError

EXECUTORS = ("local", "ray")
INSTALL_HINT = ("--executor ray needs Ray, an optional extra: pip install -e '.[ray]' (or pip install "
                "'memora-graph[ray]'); on a cluster, every node needs it, with memora-graph itself")
DEFAULT_RETRIES = 2


@dataclass
class Executor:
    """Settings of where work runs. `local` keeps today's behaviour; `ray` sends one task per
    participant (or evaluation shard) to `address` (None: start a local Ray instance with
    `num_cpus`, default every core). A failed task is tried again `retries` times. `base_urls`
    are the model servers tasks spread over (task i uses base_urls[i % n]). `shared`, a directory
    every node and the driver see at the same path, carries finished databases instead of Ray's
    object store. `fail_attempts` (tests only): participant or shard -> how many of its first
    attempts fail on purpose, before any work."""

    name: str = "local"
    address: str | None = None
    retries: int = DEFAULT_RETRIES
    base_urls: list[str] = field(default_factory=list)
    shared: str | None = None
    num_cpus: int | None = None
    fail_attempts: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.name not in EXECUTORS:
            raise MemoraError(f"--executor must be one of {', '.join(EXECUTORS)}, not {self.name!r}")
        if self.retries < 0:
            raise MemoraError(f"--retries must be 0 or more, not {self.retries}")
        if self.name == "local" and self.address:
            raise MemoraError("--ray-address applies with --executor ray")
        if self.name == "local" and self.shared:
            raise MemoraError("--ray-shared applies with --executor ray")
        if self.name == "local" and len(self.base_urls) > 1:
            raise MemoraError("a list of --base-url servers is spread over Ray tasks: add --executor ray "
                              "(the local executor talks to one server)")

    @property
    def remote(self) -> bool:
        return self.name == "ray"

    def base_url(self, i: int) -> str | None:
        return self.base_urls[i % len(self.base_urls)] if self.base_urls else None


def split_urls(text: str | None) -> list[str]:
    """`--base-url` as a list: one URL, or several separated by commas."""
    return [u.strip() for u in (text or "").split(",") if u.strip()]


class TasksFailed(MemoraError):
    """Some participants (or shards) failed on every attempt; the others were installed."""

    def __init__(self, message: str, failed: dict[str, str]):
        super().__init__(message)
        self.failed = failed


def make_executor(name: str | None, address: str | None = None, retries: int | None = None,
                  base_url: str | None = None, shared: str | None = None) -> Executor:
    """The executor of a command's options; `ray` checks that Ray is installed."""
    ex = Executor(name or "local", address=address or None,
                  retries=DEFAULT_RETRIES if retries is None else retries, base_urls=split_urls(base_url),
                  shared=shared or None)
    if ex.remote:
        require_ray()
    return ex


def require_ray():
    """The `ray` module, or an error that says how to install it."""
    try:
        import ray
    except ImportError:
        raise MemoraError(INSTALL_HINT) from None
    return ray


def cpu_count() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)

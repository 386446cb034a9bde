"""The operating system's half of the ad-hoc Cypher path: a query child confines itself with
Linux Landlock before Kùzu runs the statement.

The read guard (memora_graph/cypher_guard.py) is a word list: it explains refusals, but Kùzu
can open any file the process can, so a statement the guard misjudges would read it. A confined
child cannot: the kernel lets it open only the one database file it was given (read-only) or,
with `--write`, that database's private working folder (see memora_graph/adhoc.py); every other
path (the rest of the bank, other participants, /etc, /tmp, home) is refused, and so are TCP
bind/connect (ABI 4+), abstract UNIX sockets and signals to processes outside it (ABI 6+).
Everything the child needs afterwards is imported and opened before it confines itself.

Landlock needs no privilege (Linux 5.13+). Where the kernel has none, `mode()` says so and the
callers decide: `memora query` warns, `memora serve` offers no Cypher tool unless started with
`--unconfined-cypher`. The binding is landlockpy (PyPI, 0BSD), which masks the rights asked for
with what the running kernel supports (best effort) and reports the ABI.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

# Test-only switches, read by the query child (and by `mode()`): simulate a kernel without
# Landlock, and skip the read guard so that tests show the kernel alone stops each escape.
NO_LANDLOCK_ENV = "MEMORA_TEST_NO_LANDLOCK"
NO_GUARD_ENV = "MEMORA_TEST_NO_GUARD"
NET_ABI = 4  # TCP bind/connect rules
SCOPE_ABI = 6  # abstract UNIX sockets, signals


@dataclass(frozen=True)
class Mode:
    """Which confinement a query child gets on this machine."""

    abi: int  # Landlock ABI of the running kernel; 0 where there is none
    why: str = ""  # why there is none

    @property
    def confined(self) -> bool:
        return self.abi > 0

    def describe(self) -> str:
        if not self.confined:
            return f"unconfined: {self.why}; only the read guard stands between a query and the files on disk"
        parts = ["files"]
        parts.append("network" if self.abi >= NET_ABI else "not the network (needs Landlock ABI 4, Linux 6.7)")
        if self.abi >= SCOPE_ABI:
            parts.append("signals and abstract sockets")
        return f"kernel-confined (Landlock ABI {self.abi}): {', '.join(parts)}"


def mode() -> Mode:
    """The confinement this machine offers to a query child."""
    if os.environ.get(NO_LANDLOCK_ENV):
        return Mode(0, f"Landlock switched off by {NO_LANDLOCK_ENV} (a test)")
    if not sys.platform.startswith("linux"):
        return Mode(0, f"Landlock is a Linux feature; this is {sys.platform}")
    try:
        import landlockpy
    except ImportError:
        return Mode(0, "the landlockpy package is not installed")
    try:
        abi = landlockpy.abi_version()
    except Exception as exc:  # noqa: BLE001 - any failure of the probe means no confinement
        return Mode(0, f"the Landlock probe failed ({exc})")
    if abi < 1:
        return Mode(0, "this kernel offers no Landlock (Linux 5.13+ with Landlock enabled is needed)")
    return Mode(abi)


class ConfinementError(RuntimeError):
    """The child could not confine itself; it runs nothing."""


def confine(read_files: list[Path], work_dir: Path | None = None) -> int:
    """Confine this process (and every thread or process it starts afterwards) for good: it may
    read `read_files` (each one file) and, if `work_dir` is given, read, create, write, truncate
    and remove files inside that one folder; nothing else on disk, no TCP, no signals or abstract
    sockets outside. Returns the Landlock ABI used. Call it before any thread whose file access
    matters is started: without ABI 8's TSYNC, threads that already exist keep their rights."""
    m = mode()
    if not m.confined:
        raise ConfinementError(m.describe())
    import landlockpy as ll

    fs, net, scope = ll.fs_for_abi(m.abi), ll.net_for_abi(m.abi), ll.scope_for_abi(m.abi)
    read = ll.AccessFS.READ_FILE
    work = (ll.AccessFS.READ_FILE | ll.AccessFS.READ_DIR | ll.AccessFS.WRITE_FILE | ll.AccessFS.TRUNCATE
            | ll.AccessFS.MAKE_REG | ll.AccessFS.REMOVE_FILE)
    try:
        with ll.Ruleset(handled_fs=fs, handled_net=net, scoped=scope) as rules:
            for path in read_files:
                rules.allow_path(path, read)
            if work_dir is not None:
                rules.allow_path(work_dir, work)
            rules.restrict(ll.RestrictFlag.TSYNC)  # dropped where the kernel lacks it (ABI < 8)
    except OSError as exc:
        raise ConfinementError(f"Landlock refused the rules ({exc})") from exc
    return m.abi

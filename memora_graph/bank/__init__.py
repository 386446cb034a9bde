"""A memory bank: a directory with one Kùzu database per participant and a manifest.

Memory is personal: one file per person means a build of one participant never locks
another's memory, and forgetting a person (`Bank.forget`) removes every trace of them. The
manifest records what each write left behind: videos, record counts, and (`integrity`) the
sha256, size and rows per table of the database file after it was closed. Every open checks the
file against that record before Kùzu reads a byte of it, and refuses a database whose last
write did not finish, a write-ahead log that does not belong to it, or a file the manifest does
not list. `memora verify BANK` gives the full report; `--no-verify` bypasses the checks.

- `manifest`: the manifest file, participant ids, what a build records;
- `locks`: the manifest and participant locks, and the write marks of unfinished writes;
- `integrity`: the integrity records, the checks before every open, the bank's notices;
- `core`: `Bank`, which composes the three, opens databases, adds indexes and forgets.
"""

from memora_graph.bank.core import Bank, check_writable
from memora_graph.bank.integrity import CHECKED_COUNTS, NO_VERIFY_ENV, VERIFIED, verify_default
from memora_graph.bank.locks import BUILD_LOCK, pid_alive
from memora_graph.bank.manifest import FORMAT, MANIFEST, is_participant_id, parse_participants

__all__ = ["BUILD_LOCK", "CHECKED_COUNTS", "FORMAT", "MANIFEST", "NO_VERIFY_ENV", "VERIFIED", "Bank",
           "check_writable", "is_participant_id", "parse_participants", "pid_alive", "verify_default"]

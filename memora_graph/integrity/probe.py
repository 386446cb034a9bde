"""Child process of `memora_graph.files.probe`: open one database read-only and print its rows per table as
JSON. Run as `python -m memora_graph.integrity.probe DB PARTICIPANT [PARENT_PID]`; a crash here (SIGSEGV on
a damaged file or a foreign write-ahead log) only ends this process."""

from __future__ import annotations

import json
import sys


def main(argv: list[str]) -> int:
    from memora_graph.errors import MemoraError
    from memora_graph.files import die_with_parent
    from memora_graph.store import Store

    db, participant, *parent = argv
    if parent:  # asked by a process that may be killed: go with it, not hold the file under the next one
        die_with_parent(int(parent[0]))
    try:
        with Store(db, read_only=True, buffer_pool_bytes=256 << 20) as store:  # a damaged file cannot take the memory
            tables = store.table_counts(participant)
            counts = store.rows("store_counts", participant=participant)[0] if "Video" in tables else {}
    except MemoraError as exc:
        print(str(exc))
        return 1
    print(json.dumps({"tables": tables, "counts": {k: int(v or 0) for k, v in counts.items()}}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

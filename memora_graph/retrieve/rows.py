"""Rows of a by-key named query kept with the persisted tool stores, so that a tool reads the
records it returns from memory-mapped arrays instead of one Kùzu lookup each.

`search_activities` reads about 30 segments a call (its results and their neighbours) and
`search` about 14, by key (`_tool_segment`): ~0.65 ms of CPU each in Kùzu, most of those tools'
own work at 100 h. `KeyedRows` holds every row of such a query: the keys sorted (a fixed-width
array, found by binary search) and each row as a JSON list of the query's columns in one byte
array, read back as the dict the query returns. A key it does not hold is not in the database
the stores were computed from (they are checked against its sha256); the view reads Kùzu for a
key a remembered moment wrote since (`MemoryView.by_id`)."""

from __future__ import annotations

import json

import numpy as np
import polars as pl

ARRAYS = ("keys", "offsets", "rows")


class KeyedRows:
    def __init__(self, columns: list[str], arrays: dict[str, np.ndarray]):
        self.columns = columns
        self._keys, self._offsets, self._rows = arrays["keys"], arrays["offsets"], arrays["rows"]

    @classmethod
    def build(cls, frame: pl.DataFrame, key: str = "id") -> KeyedRows:
        """From a named query's rows (one per key)."""
        frame = frame.sort(key)
        columns = frame.columns
        chunks = [json.dumps(list(r), ensure_ascii=False).encode("utf-8") for r in frame.iter_rows()]
        offsets = np.zeros(len(chunks) + 1, dtype=np.int64)
        np.cumsum([len(c) for c in chunks], out=offsets[1:])
        keys = frame[key].to_list()
        if len(set(keys)) != len(keys):
            raise ValueError(f"{key} is not a key of these rows")
        width = max((len(k) for k in keys), default=1)
        return cls(columns, {"keys": np.asarray(keys, dtype=f"<U{width}"), "offsets": offsets,
                             "rows": np.frombuffer(b"".join(chunks), dtype=np.uint8).copy()})

    def arrays(self) -> tuple[dict, dict[str, np.ndarray]]:
        return {"columns": self.columns}, {"keys": self._keys, "offsets": self._offsets, "rows": self._rows}

    @classmethod
    def from_arrays(cls, header: dict, arrays: dict[str, np.ndarray]) -> KeyedRows:
        if not isinstance(header.get("columns"), list) or len(arrays["offsets"]) != len(arrays["keys"]) + 1:
            raise ValueError("keyed rows: header or offsets do not fit the keys")
        return cls(header["columns"], arrays)

    def get(self, key: str) -> dict | None:
        i = int(np.searchsorted(self._keys, key))
        if i >= len(self._keys) or self._keys[i] != key:
            return None
        lo, hi = int(self._offsets[i]), int(self._offsets[i + 1])
        return dict(zip(self.columns, json.loads(self._rows[lo:hi].tobytes())))

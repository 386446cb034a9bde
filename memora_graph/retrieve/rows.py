"""Rows of a by-key named query kept with the persisted tool stores, so that a tool reads the
records it returns from memory-mapped arrays instead of one Kùzu lookup each.

`get_state_at_time` reads a video's state entries (`_tool_video_events`: ~2,650 rows, 17 ms of
Kùzu CPU, with spikes to 70 ms); `search_activities` reads about 30 segments a call (its results and their neighbours) and
`search` about 14, by key (`_tool_segment`): ~0.65 ms of CPU each in Kùzu, most of those tools'
own work at 100 h. `KeyedRows` holds every row of such a query: the keys sorted (a fixed-width
array, found by binary search) and each row as a JSON list of the query's columns in one byte
array, read back as the dict the query returns. A key it does not hold is not in the database
the stores were computed from (they are checked against its sha256); the view reads Kùzu for a
key a remembered moment wrote since (`MemoryView.by_id`)."""

from __future__ import annotations

import json
from array import array
from collections.abc import Iterable

import numpy as np
import polars as pl

ARRAYS = ("keys", "offsets", "rows")


def pack(chunks: Iterable[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """(offsets, bytes): byte strings laid end to end in one uint8 array, appended one at a
    time, and the n + 1 offsets of their ends. A list of the strings joined, then copied, held
    them three times over (the history's entries were ~1 GB that way at 1,000 h)."""
    buf, ends = bytearray(), array("q", [0])
    for b in chunks:
        buf += b
        ends.append(len(buf))
    return np.asarray(ends, dtype=np.int64), np.frombuffer(buf, dtype=np.uint8)


def find_sorted(keys: np.ndarray, key: str) -> int | None:
    """Where `key` is in the sorted string array `keys` (None: not there). The key is searched
    as the array's own type: a str longer than a '<U13' array's width makes numpy cast every
    element to the longer width first (a remembered segment id "live-perf#t0012" against 360,015
    ids at 1,000 h: ~25 ms per search, where it takes microseconds); a key longer than the width
    is none of the array's strings."""
    if keys.dtype.kind == "U":
        if len(key) > keys.dtype.itemsize // 4:
            return None
        i = int(np.searchsorted(keys, np.asarray(key, dtype=keys.dtype)))
    else:
        i = int(np.searchsorted(keys, key))
    return i if i < len(keys) and keys[i] == key else None


def find_sorted_many(keys: np.ndarray, wanted: list[str]) -> list[int | None]:
    """`find_sorted` of each key, with one search for all of them (a search per key costs ~10 us
    at 1,000 h; `search` looks up ~100). The same width rule: a key longer than a '<U' array's
    width is none of its strings (searched as "", so no element is cast wider)."""
    n = len(keys)
    if not wanted or not n:
        return [None] * len(wanted)
    fits = [True] * len(wanted)
    if keys.dtype.kind == "U":
        width = keys.dtype.itemsize // 4
        fits = [len(k) <= width for k in wanted]
        at = np.searchsorted(keys, np.asarray([k if f else "" for k, f in zip(wanted, fits)], dtype=keys.dtype))
    else:
        at = np.searchsorted(keys, wanted)
    return [i if f and i < n and keys[i] == k else None for k, f, i in zip(wanted, fits, at.tolist())]


class KeyedRows:
    """The rows of a by-key query (`get(key)`: its row), or of a query giving each key a list of
    rows in order (`grouped`: `rows(key)`, as `_tool_video_events` gives a video's entries)."""

    def __init__(self, columns: list[str], arrays: dict[str, np.ndarray], grouped: bool = False):
        self.columns, self.grouped = columns, grouped
        self._keys, self._offsets, self._rows = arrays["keys"], arrays["offsets"], arrays["rows"]

    @classmethod
    def build(cls, frame: pl.DataFrame, key: str = "id") -> KeyedRows:
        """From a named query's rows (one per key)."""
        frame = frame.sort(key)
        columns = frame.columns
        keys = frame[key].to_list()
        if len(set(keys)) != len(keys):
            raise ValueError(f"{key} is not a key of these rows")
        offsets, rows = pack(json.dumps(list(r), ensure_ascii=False).encode("utf-8") for r in frame.iter_rows())
        width = max((len(k) for k in keys), default=1)
        return cls(columns, {"keys": np.asarray(keys, dtype=f"<U{width}"), "offsets": offsets, "rows": rows})

    @classmethod
    def build_grouped(cls, frame: pl.DataFrame, key: str, order: tuple[str, ...]) -> KeyedRows:
        """From a query's rows of every key; each key's rows sorted by `order` (the per-key
        query's ORDER BY, a unique key). Sorted here: a participant-wide fetch of Kùzu came
        back out of its ORDER BY (10 h synthetic bank, `_tool_video_events_all`)."""
        frame = frame.sort([key, *order])
        columns = [c for c in frame.columns if c != key]
        keys = []

        def chunks():
            for (k,), part in frame.group_by(key, maintain_order=True):
                keys.append(k)
                yield json.dumps([list(r) for r in part.select(columns).iter_rows()], ensure_ascii=False).encode("utf-8")

        offsets, rows = pack(chunks())
        width = max((len(k) for k in keys), default=1)
        return cls(columns, {"keys": np.asarray(keys, dtype=f"<U{width}"), "offsets": offsets, "rows": rows},
                   grouped=True)

    def arrays(self) -> tuple[dict, dict[str, np.ndarray]]:
        return {"columns": self.columns, "grouped": self.grouped}, {"keys": self._keys, "offsets": self._offsets, "rows": self._rows}

    @classmethod
    def from_arrays(cls, header: dict, arrays: dict[str, np.ndarray]) -> KeyedRows:
        if not isinstance(header.get("columns"), list) or len(arrays["offsets"]) != len(arrays["keys"]) + 1:
            raise ValueError("keyed rows: header or offsets do not fit the keys")
        return cls(header["columns"], arrays, bool(header.get("grouped")))

    def _raw(self, key: str):
        i = find_sorted(self._keys, key)
        if i is None:
            return None
        lo, hi = int(self._offsets[i]), int(self._offsets[i + 1])
        return json.loads(self._rows[lo:hi].tobytes())

    def get(self, key: str) -> dict | None:
        """A by-key query's row for `key` (None: the query returns none)."""
        raw = self._raw(key)
        return None if raw is None else dict(zip(self.columns, raw))

    def rows(self, key: str) -> list[dict]:
        """A grouped query's rows for `key`, in order."""
        cols = self.columns
        return [dict(zip(cols, r)) for r in self._raw(key) or ()]

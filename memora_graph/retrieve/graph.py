"""The observation graph of one participant's memory: which entities were seen in which segments and
where, and which entities occur together, held as flat arrays so that the persisted tool stores
reopen it memory-mapped (memora_graph/retrieve/persist.py) and the view reads it
(memora_graph/retrieve/view.py) without rebuilding anything."""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable

import numpy as np


class ObservationGraph:
    """Entity <-> segment edges (StateEvent -OBSERVED_IN-> Segment), with where each was seen, and
    the entity co-occurrence counts (segments two entities share), computed once. The counts are
    kept sparse (pairs that co-occur, sorted): a dense entity x segment incidence product grows as
    entities^2 x segments and does not fit a 1,000-hour memory (docs/performance.md, "Memory at scale").

    Everything is held as flat arrays (`arrays()`; `from_arrays` reopens them memory-mapped from
    the persisted tool stores without rebuilding anything): segment ids sorted, each segment's
    entities between two offsets, each entity's places and counts the same way. Lookups answer
    as the dicts of sets and Counters did: `segment_entities.get(segment, ())`,
    `entity_places.get(entity, Counter())`, `used_with(entity)`."""

    def __init__(self, rows: Iterable[dict]):
        seg_sets: dict[str, set[str]] = defaultdict(set)
        places: dict[str, Counter[str]] = defaultdict(Counter)
        for r in rows:
            seg_sets[r["segment"]].add(r["entity"])
            if r["location"]:
                places[r["entity"]][r["location"]] += int(r["n"])
        entities = sorted({e for es in seg_sets.values() for e in es})
        row = {e: i for i, e in enumerate(entities)}
        members = [sorted(row[e] for e in es) for es in seg_sets.values()]  # rows grouped by segment
        pairs, counts = _cooccurrence(len(entities), members)
        segments = sorted(seg_sets)
        seg_offsets, seg_entities = _csr([sorted(row[e] for e in seg_sets[s]) for s in segments])
        locations = sorted({loc for c in places.values() for loc in c})
        loc_row = {loc: i for i, loc in enumerate(locations)}
        per_entity = [sorted(places.get(e, {}).items()) for e in entities]
        place_offsets, place_loc = _csr([[loc_row[loc] for loc, _ in ps] for ps in per_entity])
        place_n = np.fromiter((n for ps in per_entity for _, n in ps), dtype=np.int64, count=len(place_loc))
        width = max((len(s) for s in segments), default=1)
        self._set(entities, locations, np.asarray(segments, dtype=f"<U{width}"), seg_offsets, seg_entities,
                  place_offsets, place_loc, place_n, pairs, counts)

    def _set(self, entities, locations, segments, seg_offsets, seg_entities, place_offsets, place_loc, place_n,
             pairs, counts) -> None:
        self.entities, self.locations = entities, locations
        self._row = {e: i for i, e in enumerate(entities)}
        self._segments, self._seg_offsets, self._seg_entities = segments, seg_offsets, seg_entities
        self._place_offsets, self._place_loc, self._place_n = place_offsets, place_loc, place_n
        self._pairs, self._counts = pairs, counts
        self.segment_entities = _SegmentEntities(self)
        self.entity_places = _EntityPlaces(self)

    def arrays(self) -> tuple[dict, dict[str, np.ndarray]]:
        """(JSON-ready header: entity ids, locations; the arrays), as `from_arrays` reads them."""
        return ({"entities": self.entities, "locations": self.locations},
                {"segments": self._segments, "seg_offsets": self._seg_offsets, "seg_entities": self._seg_entities,
                 "place_offsets": self._place_offsets, "place_loc": self._place_loc, "place_n": self._place_n,
                 "pairs": self._pairs, "counts": self._counts})

    @classmethod
    def from_arrays(cls, header: dict, arrays: dict[str, np.ndarray]) -> ObservationGraph:
        g = cls.__new__(cls)
        g._set(header["entities"], header["locations"], *(arrays[k] for k in (
            "segments", "seg_offsets", "seg_entities", "place_offsets", "place_loc", "place_n", "pairs", "counts")))
        return g

    def _segment(self, segment: str) -> int | None:
        i = int(np.searchsorted(self._segments, segment))
        return i if i < len(self._segments) and self._segments[i] == segment else None

    def used_with(self, entity: str, k: int = 5) -> list[tuple[str, int]]:
        """The entities seen in the most of this entity's segments."""
        i = self._row.get(entity)
        if i is None:
            return []
        n = len(self.entities)
        lo, hi = np.searchsorted(self._pairs, [i * n, (i + 1) * n])
        row = zip((self._pairs[lo:hi] - i * n).tolist(), self._counts[lo:hi].tolist())
        order = sorted(row, key=lambda jc: (-jc[1], self.entities[jc[0]]))[:k]
        return [(self.entities[j], int(c)) for j, c in order]


class _SegmentEntities:
    """segment id -> the set of entity ids observed in it (read from the graph's arrays)."""

    def __init__(self, graph: ObservationGraph):
        self._g = graph

    def get(self, segment: str, default=None):
        g = self._g
        i = g._segment(segment)
        if i is None:
            return default
        return {g.entities[j] for j in g._seg_entities[g._seg_offsets[i]:g._seg_offsets[i + 1]].tolist()}

    def __contains__(self, segment: str) -> bool:
        return self._g._segment(segment) is not None

    def __len__(self) -> int:
        return len(self._g._segments)


class _EntityPlaces:
    """entity id -> Counter of the places it was seen at (observations per place)."""

    def __init__(self, graph: ObservationGraph):
        self._g = graph

    def get(self, entity: str, default=None):
        g = self._g
        i = g._row.get(entity)
        if i is None:
            return default
        lo, hi = int(g._place_offsets[i]), int(g._place_offsets[i + 1])
        if lo == hi:
            return default
        return Counter(dict(zip((g.locations[j] for j in g._place_loc[lo:hi].tolist()), g._place_n[lo:hi].tolist())))


def _csr(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    offsets = np.zeros(len(lists) + 1, dtype=np.int64)
    np.cumsum([len(x) for x in lists], out=offsets[1:])
    flat = np.fromiter((v for x in lists for v in x), dtype=np.int32, count=int(offsets[-1]))
    return offsets, flat


def _cooccurrence(n: int, members: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """(sorted keys i * E + j, segments shared) for every ordered pair i != j seen together."""
    seg = np.repeat(np.arange(len(members)), [len(m) for m in members])
    ent = np.fromiter((i for m in members for i in m), dtype=np.int64, count=len(seg))
    a_parts, b_parts = [], []
    for d in range(1, max((len(m) for m in members), default=0)):
        same = seg[:-d] == seg[d:]  # edges d apart within one segment (rows are grouped by segment)
        a_parts += [ent[:-d][same], ent[d:][same]]
        b_parts += [ent[d:][same], ent[:-d][same]]
    if not a_parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    keys = np.concatenate(a_parts) * n + np.concatenate(b_parts)
    return np.unique(keys, return_counts=True)

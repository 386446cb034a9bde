"""The observation graph of one participant's memory: which entities were seen in which segments and
where, and which entities occur together, held as flat arrays so that the persisted tool stores
reopen it memory-mapped (memora_graph/retrieve/persist.py) and the view reads it
(memora_graph/retrieve/view.py) without rebuilding anything."""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable

import numpy as np

from memora_graph.retrieve.rows import find_sorted, find_sorted_many


class ObservationGraph:
    """Entity <-> segment edges (StateEvent -OBSERVED_IN-> Segment), with where each was seen, and
    the entity co-occurrence counts (segments two entities share), computed once. The counts are
    kept sparse (pairs that co-occur, sorted): a dense entity x segment incidence product grows as
    entities^2 x segments and does not fit a 1,000-hour memory (docs/findings/scale-first-runs.md).

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
        # plain arrays over the mappings (slicing a np.memmap makes a memmap object: ~10 us each)
        segments, seg_offsets, seg_entities, place_offsets, place_loc, place_n, pairs, counts = (np.asarray(a) for a in (
            segments, seg_offsets, seg_entities, place_offsets, place_loc, place_n, pairs, counts))
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
        return find_sorted(self._segments, segment)

    def used_with(self, entity: str, k: int = 5) -> list[tuple[str, int]]:
        """The entities seen in the most of this entity's segments."""
        i = self._row.get(entity)
        added = self.__dict__.get("_added")
        if i is not None and (added is None or entity not in added.pairs):
            # the pairs name each other entity once, in row order, which is id order (`entities` is
            # sorted): the k largest counts, ties by id, without a Counter of every co-occurring entity
            n = len(self.entities)
            lo, hi = np.searchsorted(self._pairs, [i * n, (i + 1) * n])
            others = np.asarray(self._pairs[lo:hi]) - i * n
            counts = np.asarray(self._counts[lo:hi])
            order = np.lexsort((others, -counts))[:k]
            return [(self.entities[j], int(c)) for j, c in zip(others[order].tolist(), counts[order].tolist())]
        counts: Counter[str] = Counter()
        if i is not None:
            n = len(self.entities)
            lo, hi = np.searchsorted(self._pairs, [i * n, (i + 1) * n])
            for j, c in zip((self._pairs[lo:hi] - i * n).tolist(), self._counts[lo:hi].tolist()):
                counts[self.entities[j]] += int(c)
        if added is not None:
            for b, c in added.pairs.get(entity, {}).items():
                counts[b] += c
        order = sorted(counts.items(), key=lambda ec: (-ec[1], ec[0]))[:k]
        return [(e, int(c)) for e, c in order]

    def add(self, segment: str, observations: list[tuple[str, str]]) -> None:
        """A remembered segment's observations ((entity, location) of each state event with an
        action): its edges, places and the pairs it adds to the co-occurrence counts, kept in a
        small overlay beside the arrays (sorted, perhaps memory-mapped: not rebuilt per moment)."""
        seen = [(e, loc) for e, loc in observations if e]
        if not seen:
            return
        added = self.__dict__.setdefault("_added", _Added())
        old = set(self.segment_entities.get(segment, ()) or ())
        new = {e for e, _ in seen} - old
        for e, loc in seen:
            if loc:
                added.places[e][loc] += 1
        for a in new:
            for b in old | (new - {a}):
                added.pairs[a][b] += 1
                if b in old:
                    added.pairs[b][a] += 1
        added.segments[segment] = old | new


class _Added:
    """What remembered segments added to an observation graph since its arrays were made."""

    def __init__(self):
        self.segments: dict[str, set[str]] = {}
        self.places: dict[str, Counter[str]] = defaultdict(Counter)
        self.pairs: dict[str, Counter[str]] = defaultdict(Counter)


class _SegmentEntities:
    """segment id -> the set of entity ids observed in it (read from the graph's arrays)."""

    def __init__(self, graph: ObservationGraph):
        self._g = graph

    def get(self, segment: str, default=None):
        g = self._g
        added = g.__dict__.get("_added")
        if added is not None and segment in added.segments:
            return set(added.segments[segment])
        i = g._segment(segment)
        return default if i is None else self._at(i)

    def _at(self, i: int) -> set[str]:
        """The entity ids of the arrays' i-th segment."""
        g = self._g
        return {g.entities[j] for j in g._seg_entities[g._seg_offsets[i]:g._seg_offsets[i + 1]].tolist()}

    def many(self, segments: list[str]) -> list[set[str] | None]:
        """`get(s)` of each segment, found in the sorted ids with one search for all of them (a
        search per id costs ~10 us at 1,000 h: a `search` call ranks ~100 segments)."""
        g = self._g
        if not segments:
            return []
        added = g.__dict__.get("_added") or _Added()
        out: list[set[str] | None] = []
        for s, i in zip(segments, find_sorted_many(g._segments, segments)):
            if s in added.segments:
                out.append(set(added.segments[s]))
            elif i is not None:
                out.append(self._at(i))
            else:
                out.append(None)
        return out

    def __contains__(self, segment: str) -> bool:
        added = self._g.__dict__.get("_added")
        return (added is not None and segment in added.segments) or self._g._segment(segment) is not None

    def __len__(self) -> int:
        added = self._g.__dict__.get("_added")
        extra = 0 if added is None else sum(1 for s in added.segments if self._g._segment(s) is None)
        return len(self._g._segments) + extra


class _EntityPlaces:
    """entity id -> Counter of the places it was seen at (observations per place)."""

    def __init__(self, graph: ObservationGraph):
        self._g = graph

    def get(self, entity: str, default=None):
        g = self._g
        added = g.__dict__.get("_added")
        more = added.places.get(entity) if added is not None else None
        i = g._row.get(entity)
        lo, hi = (0, 0) if i is None else (int(g._place_offsets[i]), int(g._place_offsets[i + 1]))
        if lo == hi and not more:
            return default
        out = Counter(dict(zip((g.locations[j] for j in g._place_loc[lo:hi].tolist()), g._place_n[lo:hi].tolist())))
        if more:
            out.update(more)
        return out


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

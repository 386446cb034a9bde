"""Object histories summarised once, so that `get_object_history` reads what it answers with.

The tool answers with an object's per-video summary (observations, first and last time, states
and places in order of appearance, final state and place), the states and places it was ever
seen in, its first 20 segments, its last `max_entries` moves and its last `max_entries` entries.
Read from Kùzu, every call walked and sorted the object's whole history (about 100,000 entries
for the most-used object at 1,000 h: ~0.5 s). `HistoryIndex` holds, per entity:

- the part of the answer that does not depend on `max_entries` (the per-video summary, the states
  and places, the first 20 segments), as one small JSON document in a byte array;
- the history in order as flat arrays (entry ids, video, turn, time, place), and the positions of
  its moves, so that the last N entries and the last N moves are slices.

It is computed once from one participant-wide columnar fetch (`_tool_history_all`) when the tool
stores are written (retrieve/persist.py) and reopened memory-mapped; a call then reads one
entity's JSON document and at most 2 x 1,000 array rows, whatever the hours. `outline_parts`
is the same answer computed from one entity's outline as Kùzu returns it (the view's path when
no persisted stores are open, or for an entity a remembered moment has added to since they were
written); tests/retrieve/test_history.py checks that both give the same parts.
"""

from __future__ import annotations

import heapq
import json
from dataclasses import dataclass

import numpy as np
import polars as pl

from memora_graph.records import segment_id
from memora_graph.retrieve.rows import pack

ARRAYS = ("offsets", "ids", "video", "turn", "t", "loc", "move_offsets", "moves", "doc_offsets", "docs",
          "entry_offsets", "entries")
# the fields of one entry as _tool_history_entry returns them (each entry is kept as a JSON list of these)
ENTRY_FIELDS = ("id", "video", "turn", "t", "state", "location", "zone", "held_by", "relative_to", "relation", "action",
                "narration", "op")
EVIDENCE_SEGMENTS = 20  # the first segments (in id order) an answer cites


@dataclass
class HistoryParts:
    """What get_object_history answers with from the history (the entity's own record aside)."""
    total: int
    videos: list[dict]
    states: list[str]  # every state observed, sorted
    locations: list[str]  # every place observed, sorted
    segments: list[str]  # the first EVIDENCE_SEGMENTS segment ids, sorted
    transitions: list[dict]  # the last max_entries moves, oldest first
    tail_ids: list[str]  # the ids of the last max_entries entries, oldest first
    tail: list[dict] | None = None  # those entries whole (as _tool_history_entry reads them), where kept


def _named(col: str) -> pl.Expr:
    return pl.col(col).is_not_null() & (pl.col(col) != "")


def _per_video(frame: pl.DataFrame, by: list[str]) -> pl.DataFrame:
    return frame.group_by(by, maintain_order=True).agg(
        pl.len().alias("observations"), pl.col("t").first().alias("first_t"), pl.col("t").last().alias("last_t"),
        pl.col("state").filter(_named("state")).unique(maintain_order=True).alias("states"),
        pl.col("location").filter(_named("location")).unique(maintain_order=True).alias("locations"),
        pl.col("state").last().alias("final_state"), pl.col("location").last().alias("final_location"))


def _video_record(v: dict) -> dict:
    return {"video": v["video"], "observations": int(v["observations"]), "first_t": v["first_t"], "last_t": v["last_t"],
            "states": v["states"], "locations": v["locations"], "final_state": v["final_state"],
            "final_location": v["final_location"]}


def outline_parts(outline: pl.DataFrame, max_entries: int) -> HistoryParts:
    """The parts from one entity's outline (id, video, turn, t, state, location in history order)."""
    total = outline.height
    keep = max_entries if max_entries and total > max_entries else total
    moved = (outline.with_row_index("i")
             .with_columns(prev=pl.col("location").shift(1), prev_video=pl.col("video").shift(1))
             .filter((pl.col("i") > 0) & pl.col("location").ne_missing(pl.col("prev")) & _named("location")))
    if max_entries:
        moved = moved.tail(max_entries)
    transitions = [{"video": r["video"], "t": r["t"], "from": r["prev"], "to": r["location"],
                    "across_videos": r["video"] != r["prev_video"],
                    "segment_id": segment_id(r["video"], int(r["turn"])), "event_id": r["id"]} for r in moved.iter_rows(named=True)]
    videos = [_video_record(v) for v in _per_video(outline, ["video"]).iter_rows(named=True)]
    segments = sorted({segment_id(v, int(t)) for v, t in outline.select("video", "turn").unique().iter_rows()})
    return HistoryParts(
        total=total, videos=videos,
        states=sorted(set(outline.filter(_named("state"))["state"].to_list())),
        locations=sorted(set(outline.filter(_named("location"))["location"].to_list())),
        segments=segments[:EVIDENCE_SEGMENTS], transitions=transitions,
        tail_ids=outline["id"].tail(keep).to_list() if keep else [])


class HistoryIndex:
    """Every entity's history summary and history in order, as flat arrays (see the module doc)."""

    def __init__(self, header: dict, arrays: dict[str, np.ndarray]):
        self.entities: list[str] = header["entities"]
        self.videos: list[str] = header["videos"]
        self.locations: list[str | None] = header["locations"]
        self._row = {e: i for i, e in enumerate(self.entities)}
        self._a = arrays

    def arrays(self) -> tuple[dict, dict[str, np.ndarray]]:
        return {"entities": self.entities, "videos": self.videos, "locations": self.locations}, dict(self._a)

    @classmethod
    def from_arrays(cls, header: dict, arrays: dict[str, np.ndarray]) -> HistoryIndex:
        missing = [n for n in ARRAYS if n not in arrays]
        if missing or not all(isinstance(header.get(k), list) for k in ("entities", "videos", "locations")):
            raise ValueError(f"history arrays incomplete (missing: {missing or 'header fields'})")
        return cls(header, arrays)

    @classmethod
    def build(cls, frame: pl.DataFrame) -> HistoryIndex:
        """From `_tool_history_all`'s rows (entity, id, video, turn, t, state, location, ord)."""
        frame = frame.sort(["entity", "video", "t", "ord"], maintain_order=True)
        n = frame.height
        ents = frame.group_by("entity", maintain_order=True).agg(pl.len().alias("n"))
        entities = ents["entity"].to_list()
        offsets = np.zeros(len(entities) + 1, dtype=np.int64)
        np.cumsum(ents["n"].to_numpy(), out=offsets[1:])
        videos = sorted(set(frame["video"].unique().to_list()))
        locations = sorted(set(frame["location"].unique().to_list()), key=lambda x: (x is not None, x or ""))
        vrow = {v: i for i, v in enumerate(videos)}
        lrow = {loc: i for i, loc in enumerate(locations)}
        video = np.fromiter((vrow[v] for v in frame["video"].to_list()), dtype=np.int32, count=n)
        loc = np.fromiter((lrow[x] for x in frame["location"].to_list()), dtype=np.int32, count=n)
        first = np.zeros(n, dtype=bool)
        first[offsets[:-1][offsets[:-1] < n]] = True
        prev = np.empty(n, dtype=np.int32)
        prev[0:1] = -1
        prev[1:] = loc[:-1]
        named = np.array([x is not None and x != "" for x in locations], dtype=bool)
        moved = ~first & (loc != prev) & (named[loc] if n else np.zeros(0, bool))
        moves = np.flatnonzero(moved).astype(np.int64)
        move_offsets = np.searchsorted(moves, offsets).astype(np.int64)
        ids = np.array([s.encode("utf-8") for s in frame["id"].to_list()] or [b""], dtype=np.bytes_)[:n]

        per_video = _per_video(frame, ["entity", "video"])
        segs = frame.select("entity", "video", "turn").unique(maintain_order=True)
        seg_ids: dict[str, list[str]] = {}
        for e, v, t in segs.iter_rows():
            seg_ids.setdefault(e, []).append(segment_id(v, int(t)))
        docs: dict[str, dict] = {e: {"videos": []} for e in entities}
        for v in per_video.iter_rows(named=True):
            docs[v["entity"]]["videos"].append(_video_record(v))

        def doc(e: str) -> bytes:
            d = docs.pop(e)
            d["states"] = sorted({s for v in d["videos"] for s in v["states"]})
            d["locations"] = sorted({x for v in d["videos"] for x in v["locations"]})
            d["segments"] = heapq.nsmallest(EVIDENCE_SEGMENTS, set(seg_ids.pop(e, ())))
            return json.dumps(d, ensure_ascii=False).encode("utf-8")

        doc_offsets, blob = pack(doc(e) for e in entities)
        entry_offsets, entries = pack(json.dumps(list(r), ensure_ascii=False).encode("utf-8")
                                      for r in frame.select(ENTRY_FIELDS).iter_rows())
        arrays = {"offsets": offsets, "ids": ids, "video": video, "turn": frame["turn"].to_numpy().astype(np.int64),
                  "t": frame["t"].to_numpy().astype(np.float64), "loc": loc, "move_offsets": move_offsets,
                  "moves": moves, "doc_offsets": doc_offsets, "docs": blob,
                  "entry_offsets": entry_offsets, "entries": entries}
        return cls({"entities": entities, "videos": videos, "locations": locations}, arrays)

    def parts(self, entity: str, max_entries: int) -> HistoryParts:
        """The parts for one entity: its JSON document and at most 2 x max_entries array rows."""
        a = self._a
        i = self._row.get(entity)
        if i is None:  # no state event at all
            return HistoryParts(0, [], [], [], [], [], [])
        lo, hi = int(a["offsets"][i]), int(a["offsets"][i + 1])
        doc = json.loads(a["docs"][int(a["doc_offsets"][i]):int(a["doc_offsets"][i + 1])].tobytes().decode("utf-8"))
        total = hi - lo
        keep = max_entries if max_entries and total > max_entries else total
        tail_ids = [b.decode("utf-8") for b in a["ids"][hi - keep:hi].tolist()] if keep else []
        tail = _entries(a["entries"], a["entry_offsets"][hi - keep:hi + 1]) if keep else []
        moves = a["moves"][int(a["move_offsets"][i]):int(a["move_offsets"][i + 1])]
        if max_entries:
            moves = moves[-max_entries:] if len(moves) > max_entries else moves
        video, turn, t, loc, ids = a["video"], a["turn"], a["t"], a["loc"], a["ids"]
        transitions = []
        for j in moves.tolist():
            v, pv = self.videos[int(video[j])], self.videos[int(video[j - 1])]
            transitions.append({"video": v, "t": float(t[j]), "from": self.locations[int(loc[j - 1])],
                                "to": self.locations[int(loc[j])], "across_videos": v != pv,
                                "segment_id": segment_id(v, int(turn[j])), "event_id": ids[j].decode("utf-8")})
        return HistoryParts(total=total, videos=doc["videos"], states=doc["states"], locations=doc["locations"],
                            segments=doc["segments"], transitions=transitions, tail_ids=tail_ids, tail=tail)


def _entries(blob: np.ndarray, offsets: np.ndarray) -> list[dict]:
    """The entries between consecutive `offsets` of the JSON-lists byte array, as dicts."""
    if len(offsets) < 2:
        return []
    lo, hi = int(offsets[0]), int(offsets[-1])
    raw = blob[lo:hi].tobytes()
    cuts = (offsets - lo).tolist()
    return [dict(zip(ENTRY_FIELDS, json.loads(raw[cuts[k]:cuts[k + 1]]))) for k in range(len(cuts) - 1)]

"""Flat-1D (Socratic-models style): time-stamped text records in chronological order behind one
`search` tool.

The records come from the same bank every other condition reads:
- activity facts: one per 10 s turn, "[video start-end s] summary";
- state facts: raw bank = one per object observation (nothing edited, every sighting kept);
  edited bank = one per object after online editing (its current state and location, where it
  has been, how often it was seen), as an editor that UPDATEs a fact in place would leave it;
- environment facts: one per place.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import Field

from memora_graph.baselines.common import (
    EmbeddingStore, cache_or_build, clamp_top_k, embed_query, object_label, place_name, prefetch_queries,
)
from memora_graph.baselines.common import top_k as top_k_rows
from memora_graph.retrieve.args import QueryText, ToolArgs
from memora_graph.retrieve.registry import Family, register_family, tool
from memora_graph.retrieve.results import Record, ToolResult

VERSION = "flat1d-1"


@dataclass
class FlatRecord:
    kind: str  # activity | state | environment
    video: str
    time: float
    text: str  # what the agent reads (with its time stamp)
    embed_text: str  # what is embedded (shared with Graph-2D where the content is the same)

    def as_result(self, similarity: float) -> FlatHit:
        return FlatHit(kind=self.kind, video=self.video, time=round(self.time, 2), text=self.text, similarity=similarity)


class FlatHit(Record):
    """One time-stamped text record of the Flat-1D memory."""

    kind: str  # activity | state | environment
    video: str
    time: float
    text_: str = Field(alias="text")
    similarity: float

    model_config = {"extra": "forbid", "populate_by_name": True, "serialize_by_alias": True}

    def text(self) -> str:
        return self.text_

    def from_video(self) -> str:
        return self.video


class FlatSearchResult(ToolResult):
    _optional = frozenset({"error"})
    _lists = ("results",)
    query: str
    results: list[FlatHit]
    error: str | None = None


class FlatSearchArgs(ToolArgs):
    query: QueryText = Field(description="What to look for, in words.")
    top_k: int = Field(10, description="How many records to return (at most 30).")


def _stamp(video: str, start: float, end: float | None = None) -> str:
    return f"[{video} {start:.1f}-{end:.1f}s]" if end is not None else f"[{video} {start:.1f}s]"


def build_records(records: dict[str, list[dict]], mode: str) -> list[FlatRecord]:
    out: list[FlatRecord] = []
    for s in records["segments"]:
        summary = s["summary"] or ""
        if summary:
            out.append(FlatRecord("activity", s["video"], float(s["t_start"]),
                                  f"{_stamp(s['video'], s['t_start'], s['t_end'])} {summary}", summary))
    if mode == "raw":
        for e in records["entities"]:
            label = object_label(e)
            fact = f"{label}: {e['state'] or 'seen'} at {place_name(e['location'])}"
            out.append(FlatRecord("state", e["first_video"] or "", float(e["first_seen"] or 0),
                                  f"{_stamp(e['first_video'] or '', e['first_seen'] or 0)} {fact}", fact))
    else:
        seen_at: dict[str, list[str]] = defaultdict(list)
        for x in records["state_events"]:
            loc = place_name(x["location"])
            if loc and loc not in seen_at[x["entity"]]:
                seen_at[x["entity"]].append(loc)
        for e in records["entities"]:
            label = object_label(e)
            where = ", ".join(seen_at.get(e["id"], [])[:6])
            fact = (f"{label}: now {e['state'] or 'seen'} at {place_name(e['location'])}; "
                    f"seen {e['n_observations']} times" + (f"; locations: {where}" if where else ""))
            stamp = f"[{e['first_video']} {e['first_seen'] or 0:.1f}s .. {e['last_video']} {e['last_seen'] or 0:.1f}s]"
            out.append(FlatRecord("state", e["first_video"] or "", float(e["first_seen"] or 0), f"{stamp} {fact}", fact))
    for p in records["places"]:
        zones = ", ".join(p["zones"] or [])
        fact = f"place {p['name']}" + (f" with {zones}" if zones else "")
        out.append(FlatRecord("environment", p["first_video"] or "", float(p["first_seen"] or 0),
                              f"{_stamp(p['first_video'] or '', p['first_seen'] or 0)} {fact}", fact))
    out.sort(key=lambda r: (r.video, r.time, r.kind))
    return out


class Flat1DMemory:
    """One participant's Flat-1D memory: records in chronological order plus their vectors."""

    tool_names = ("search",)

    def __init__(self, participant: str, mode: str, records: list[FlatRecord], vectors: np.ndarray):
        self.participant = participant
        self.mode = mode
        self.records = records
        self.vectors = vectors

    @classmethod
    def load(cls, bank_path: str | Path, participant: str, store: EmbeddingStore | None = None) -> Flat1DMemory:
        """Built once per bank and participant, then read from `BANK/.cache/`."""
        def build(records: dict[str, list[dict]], mode: str):
            recs = build_records(records, mode)
            return recs, [r.__dict__ for r in recs], [r.embed_text for r in recs]

        return cache_or_build(bank_path, participant, "flat1d", VERSION, store=store, build=build,
                              read=lambda mode, rows, vectors: cls(participant, mode, [FlatRecord(**r) for r in rows], vectors),
                              make=lambda mode, recs, vectors: cls(participant, mode, recs, vectors))

    def search(self, query: str, top_k: int = 10) -> FlatSearchResult:
        """The top-k records by cosine to the query (near-duplicates collapsed)."""
        query = str(query or "").strip()
        if not query:
            return FlatSearchResult(query=query, results=[], error="empty query")
        hits = top_k_rows(self.vectors, embed_query(query), clamp_top_k(top_k))
        return FlatSearchResult(query=query, results=[self.records[i].as_result(s) for i, s in hits])

    prefetch = staticmethod(prefetch_queries)

    def stats(self) -> dict:
        kinds: dict[str, int] = defaultdict(int)
        for r in self.records:
            kinds[r.kind] += 1
        return {"records": len(self.records), **dict(kinds)}


register_family(Family("flat1d", "Flat-1D chronological text records", Flat1DMemory.load))


@tool("search", family="flat1d", args=FlatSearchArgs, result=FlatSearchResult, store="Flat-1D records",
      description="Search the person's chronological text memory; returns the most similar time-stamped records.")
def flat_search(memory: Flat1DMemory, query: str, top_k: int = 10) -> FlatSearchResult:
    return memory.search(query, top_k)

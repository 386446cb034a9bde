"""Graph-2D (M3-Agent style entity-relation graph), built with networkx from the same bank.

Nodes: activity (one per 10 s turn), object (one per object record: every observation in a raw
bank, one per edited object otherwise), place, and pattern (consolidated routines, when the bank
has them; a raw bank has none). Edges: NEXT (consecutive turns of a video), USED_IN (object
observed in a turn), LOCATED_AT (object -> its place), CO_OCCURS (objects in the same turn),
HAPPENED_AT (turn -> its place), IMPLIES (pattern -> supporting turns). Adjacency is read both ways.

Read tools: `search` (12 embedding seeds, one-hop expansion that skips CO_OCCURS, at most 3
results per category, activities with their neighbouring turns as `_context`),
`get_object_history` and `get_state_at_time`.
"""

from __future__ import annotations

from collections import defaultdict
from itertools import combinations
from pathlib import Path

from typing import TYPE_CHECKING

import numpy as np
from pydantic import Field

from memora_graph.baselines.common import (
    EmbeddingStore, cache_or_build, embed_query, object_label, place_name, prefetch_queries,
)
from memora_graph.baselines.common import top_k as top_k_rows
from memora_graph.retrieve.args import QueryText, ToolArgs
from memora_graph.retrieve.registry import Family, register_family, tool
from memora_graph.retrieve.results import Model, Record, ToolErrorResult, ToolResult

if TYPE_CHECKING:  # networkx is imported where a graph is built or loaded: `memora tool` never pays for it
    import networkx as nx

VERSION = "graph2d-2"  # 2: the graph is cached as node-link JSON (data, never code), not a pickle
SEEDS = 12
PER_CATEGORY = 3
OBJECT_FALLBACK_COSINE = 0.3
CATEGORIES = {"activity": "activities", "object": "objects", "place": "environment", "pattern": "patterns"}


def build_graph(records: dict[str, list[dict]], mode: str) -> nx.Graph:
    import networkx as nx

    g = nx.Graph()
    seg_id: dict[tuple[str, int], str] = {}
    by_video: dict[str, list[dict]] = defaultdict(list)
    for s in records["segments"]:
        node = f"act:{s['id']}"
        seg_id[(s["video"], int(s["turn"]))] = node
        by_video[s["video"]].append(s)
        g.add_node(node, kind="activity", video=s["video"], turn=int(s["turn"]), t_start=float(s["t_start"]),
                   t_end=float(s["t_end"]), text=s["summary"] or "", location=s["location"] or "")
    for segs in by_video.values():
        segs.sort(key=lambda s: s["turn"])
        for a, b in zip(segs, segs[1:]):
            g.add_edge(f"act:{a['id']}", f"act:{b['id']}", rel="NEXT")
    for p in records["places"]:
        zones = ", ".join(p["zones"] or [])
        g.add_node(f"env:{p['location_id']}", kind="place", name=p["name"], video=p["first_video"] or "",
                   text=f"place {p['name']}" + (f" with {zones}" if zones else ""), location=p["location_id"])
    for n, data in list(g.nodes(data=True)):
        if data["kind"] == "activity" and g.has_node(f"env:{data['location']}"):
            g.add_edge(n, f"env:{data['location']}", rel="HAPPENED_AT")
    for e in records["entities"]:
        node = f"obj:{e['id']}"
        label = object_label(e)
        g.add_node(node, kind="object", name=e["name"] or "", label=label, video=e["first_video"] or "",
                   time=float(e["first_seen"] or 0), state=e["state"] or "", location=e["location"] or "",
                   n_observations=int(e["n_observations"] or 0),
                   text=f"{label}: {e['state'] or 'seen'} at {place_name(e['location'])}")
        if g.has_node(f"env:{e['location']}"):
            g.add_edge(node, f"env:{e['location']}", rel="LOCATED_AT")
    in_turn: dict[str, set[str]] = defaultdict(set)
    for x in records["state_events"]:
        obj, act = f"obj:{x['entity']}", seg_id.get((x["video"], int(x["turn"])))
        if act is None or not g.has_node(obj):
            continue  # an observation of a record merged away by the editor
        g.add_edge(obj, act, rel="USED_IN")
        in_turn[act].add(obj)
    for objs in in_turn.values():
        for a, b in combinations(sorted(objs), 2):
            if not g.has_edge(a, b):
                g.add_edge(a, b, rel="CO_OCCURS")
    if mode != "raw":
        for r in records["routines"]:
            steps = "; ".join(r["canonical_steps"] or [])
            objs = ", ".join(r["key_objects"] or [])
            node = f"pat:{r['id']}"
            g.add_node(node, kind="pattern", video="", time=-1.0, text=f"{r['goal']}: {steps}" + (f" (objects: {objs})" if objs else ""))
            for s in r["segments"] or []:
                if g.has_node(f"act:{s}"):
                    g.add_edge(node, f"act:{s}", rel="IMPLIES")
    return g


class NodeContext(Model):
    previous: str
    next: str


class GraphNode(Record):
    """A node of the entity-relation graph as the tools show it (activity, object, place, pattern)."""

    _optional = frozenset({"video", "turn", "time", "place", "context", "name", "state", "location", "similarity",
                           "visible_objects"})
    model_config = {"extra": "forbid", "populate_by_name": True, "serialize_by_alias": True}
    id: str
    text_: str = Field(alias="text")
    name: str | None = None
    state: str | None = None
    location: str | None = None
    video: str | None = None
    turn: int | None = None
    time: float | None = None
    place: str | None = None
    context: NodeContext | None = Field(None, alias="_context")
    similarity: float | None = None
    visible_objects: list[str] | None = None  # get_state_at_time: the objects used in that turn

    def text(self) -> str:
        return self.text_

    def from_video(self) -> str:
        return self.video or ""


class GraphSearchResult(ToolResult):
    _optional = frozenset({"activities", "objects", "environment", "patterns", "error"})
    _lists = ("activities", "objects", "environment", "patterns")
    query: str
    activities: list[GraphNode] | None = None
    objects: list[GraphNode] | None = None
    environment: list[GraphNode] | None = None
    patterns: list[GraphNode] | None = None
    error: str | None = None


class GraphHistoryResult(ToolResult):
    _optional = frozenset({"error", "match_type", "n_records", "name", "current_state", "current_location",
                           "all_locations_observed", "objects", "history", "n_history"})
    _lists = ("objects", "history")
    object_query: str
    error: str | None = None
    match_type: str | None = None
    n_records: int | None = None
    name: str | None = None
    current_state: str | None = None
    current_location: str | None = None
    all_locations_observed: list[str] | None = None
    objects: list[GraphNode] | None = None
    history: list[GraphNode] | None = None
    n_history: int | None = None


class GraphStateResult(ToolResult):
    _lists = ("moments",)
    time_seconds: float
    video_id: str
    moments: list[GraphNode]


class GraphSearchArgs(ToolArgs):
    query: QueryText = Field(description="What to look for, in words.")
    top_k_per_category: int = Field(PER_CATEGORY, description="Records per category (at most 3).")


class GraphHistoryArgs(ToolArgs):
    object_query: QueryText = Field(description="The object, in words.")


class GraphStateArgs(ToolArgs):
    time_seconds: float = Field(description="Seconds into a video.")
    video_id: str | None = Field(None, description="The video id (default: every video at that time).")


class Graph2DMemory:
    tool_names = ("search", "get_object_history", "get_state_at_time")

    def __init__(self, participant: str, mode: str, graph: nx.Graph, nodes: list[str], vectors: np.ndarray):
        self.participant = participant
        self.mode = mode
        self.graph = graph
        self.nodes = nodes
        self.vectors = vectors
        self.index = {n: i for i, n in enumerate(nodes)}
        self.kinds = np.array([graph.nodes[n]["kind"] for n in nodes])

    @classmethod
    def load(cls, bank_path: str | Path, participant: str, store: EmbeddingStore | None = None) -> Graph2DMemory:
        import networkx as nx

        def build(records: dict[str, list[dict]], mode: str):
            graph = build_graph(records, mode)
            nodes = sorted(graph.nodes)
            return ((graph, nodes), {"graph": nx.node_link_data(graph, edges="edges"), "nodes": nodes},
                    [graph.nodes[n]["text"] for n in nodes])

        def read(mode: str, data: dict, vectors: np.ndarray) -> Graph2DMemory:
            return cls(participant, mode, nx.node_link_graph(data["graph"], edges="edges"), data["nodes"], vectors)

        return cache_or_build(bank_path, participant, "graph2d", VERSION, store=store, build=build, read=read,
                              make=lambda mode, built, vectors: cls(participant, mode, *built, vectors),
                              damaged=(nx.NetworkXError,))

    prefetch = staticmethod(prefetch_queries)

    # -- rendering -------------------------------------------------------------------------
    def _view(self, node: str, similarity: float | None = None, context: bool = False) -> GraphNode:
        d = self.graph.nodes[node]
        out: dict = {"id": node, "text": d["text"]}
        if d["kind"] == "activity":
            out.update(video=d["video"], turn=d["turn"], time=d["t_start"], place=place_name(d["location"]))
            if context:
                prev = [m for m in self.graph.neighbors(node)
                        if self.graph.edges[node, m]["rel"] == "NEXT" and self.graph.nodes[m]["turn"] < d["turn"]]
                nxt = [m for m in self.graph.neighbors(node)
                       if self.graph.edges[node, m]["rel"] == "NEXT" and self.graph.nodes[m]["turn"] > d["turn"]]
                out["_context"] = {"previous": self.graph.nodes[prev[0]]["text"][:100] if prev else "",
                                   "next": self.graph.nodes[nxt[0]]["text"][:100] if nxt else ""}
        elif d["kind"] == "object":
            out.update(name=d["name"], state=d["state"], location=place_name(d["location"]), video=d["video"],
                       time=d["time"])
        if similarity is not None:
            out["similarity"] = similarity
        return GraphNode(**out)

    # -- tools -----------------------------------------------------------------------------
    def search(self, query: str, top_k_per_category: int = PER_CATEGORY) -> GraphSearchResult:
        query = str(query or "").strip()
        if not query:
            return GraphSearchResult(query=query, error="empty query")
        try:
            k = max(1, min(PER_CATEGORY, int(top_k_per_category)))
        except (TypeError, ValueError):
            k = PER_CATEGORY
        q = embed_query(query)
        scores = self.vectors @ q
        seeds = [self.nodes[i] for i, _ in top_k_rows(self.vectors, q, SEEDS)]
        candidates = set(seeds)
        for s in seeds:
            for m in self.graph.neighbors(s):
                if self.graph.edges[s, m]["rel"] != "CO_OCCURS":
                    candidates.add(m)
        ranked = sorted(candidates, key=lambda n: (-float(scores[self.index[n]]), n))
        out: dict = {c: [] for c in CATEGORIES.values()}
        for n in ranked:
            bucket = out[CATEGORIES[self.graph.nodes[n]["kind"]]]
            if len(bucket) < k:
                bucket.append(self._view(n, round(float(scores[self.index[n]]), 4), context=True))
        return GraphSearchResult(query=query, **out)

    def _match_objects(self, object_query: str) -> tuple[list[str], str]:
        q = object_query.lower().strip().replace("_", " ")
        objects = [n for n in self.nodes if self.graph.nodes[n]["kind"] == "object"]
        exact = [n for n in objects if self.graph.nodes[n]["name"].lower() == q]
        if exact:
            return exact, "exact"
        sub = [n for n in objects if q in self.graph.nodes[n]["label"].lower() or self.graph.nodes[n]["name"].lower() in q]
        if sub:
            return sub, "substring"
        hits = top_k_rows(self.vectors, embed_query(object_query), 3, mask=self.kinds == "object")
        return [self.nodes[i] for i, s in hits if s >= OBJECT_FALLBACK_COSINE], "embedding"

    def get_object_history(self, object_query: str) -> GraphHistoryResult:
        object_query = str(object_query or "").strip()
        if not object_query:
            return GraphHistoryResult(object_query=object_query, error="empty object_query")
        matched, how = self._match_objects(object_query)
        if not matched:
            return GraphHistoryResult(object_query=object_query, match_type="none", objects=[], history=[])
        seen: dict[str, dict] = {}
        for n in matched:
            for m in self.graph.neighbors(n):
                if self.graph.edges[n, m]["rel"] == "USED_IN":
                    seen.setdefault(m, self._view(m))
        history = sorted(seen.values(), key=lambda v: (v.video, v.time))
        objects = sorted((self._view(n) for n in matched), key=lambda v: (v.video, v.time))
        latest = objects[-1]
        return GraphHistoryResult(
            object_query=object_query, match_type=how, n_records=len(matched),
            name=latest.name, current_state=latest.state, current_location=latest.location,
            all_locations_observed=sorted({o.location for o in objects if o.location}),
            objects=objects[:10], history=history[:15], n_history=len(history),
        )

    def get_state_at_time(self, time_seconds: float, video_id: str | None = None) -> GraphStateResult | ToolErrorResult:
        try:
            t = float(time_seconds)
        except (TypeError, ValueError):
            return ToolErrorResult(error=f"time_seconds must be a number, got {time_seconds!r}")
        acts = [n for n in self.nodes if self.graph.nodes[n]["kind"] == "activity"
                and self.graph.nodes[n]["t_start"] <= t < self.graph.nodes[n]["t_end"]
                and (not video_id or self.graph.nodes[n]["video"] == video_id)]
        acts = sorted(acts, key=lambda n: self.graph.nodes[n]["video"])[:5]
        out = []
        for a in acts:
            view = self._view(a)
            view.visible_objects = sorted(
                {self.graph.nodes[m]["label"] + f" ({self.graph.nodes[m]['state']})"
                 for m in self.graph.neighbors(a) if self.graph.edges[a, m]["rel"] == "USED_IN"})[:12]
            out.append(view)
        return GraphStateResult(time_seconds=t, video_id=video_id or "", moments=out)

    def stats(self) -> dict:
        kinds: dict[str, int] = defaultdict(int)
        for _, d in self.graph.nodes(data=True):
            kinds[d["kind"]] += 1
        rels: dict[str, int] = defaultdict(int)
        for _, _, d in self.graph.edges(data=True):
            rels[d["rel"]] += 1
        return {"nodes": self.graph.number_of_nodes(), "edges": self.graph.number_of_edges(), **kinds, **rels}


register_family(Family("graph2d", "Graph-2D entity-relation graph", Graph2DMemory.load))


@tool("search", family="graph2d", args=GraphSearchArgs, result=GraphSearchResult, store="Graph-2D graph",
      description="Search the entity-relation graph: embedding seeds plus their one-hop neighbours; at most 3 "
                  "activities, objects, places and patterns.")
def graph_search(memory: Graph2DMemory, query: str, top_k_per_category: int = PER_CATEGORY) -> GraphSearchResult:
    return memory.search(query, top_k_per_category)


@tool("get_object_history", family="graph2d", args=GraphHistoryArgs, result=GraphHistoryResult,
      store="Graph-2D graph", description="An object's records and the activities it was used in, in time order.")
def graph_object_history(memory: Graph2DMemory, object_query: str) -> GraphHistoryResult:
    return memory.get_object_history(object_query)


@tool("get_state_at_time", family="graph2d", args=GraphStateArgs, result=GraphStateResult, store="Graph-2D graph",
      description="What was happening at a time (seconds into a video), with the objects seen then.")
def graph_state_at_time(memory: Graph2DMemory, time_seconds: float, video_id: str | None = None) -> GraphStateResult:
    return memory.get_state_at_time(time_seconds, video_id)

"""The MEMORA retrieval tools over one participant's memory (a `MemoryView`).

Each tool is a function registered with its `ToolSpec` (the `@tool` line above it: name, argument
model, result model, the store it reads, description); the spec is the one place the agent
schemas, tool-call parsing, the tool sets of the evaluation, the report's store map and the
`memora tool` / `memora tools` commands read. A tool returns a `Reply` (the arguments it echoes and
its fields), which the `@tool` wrapper turns into the typed result (`retrieve.results`):
the tool name, the participant, the arguments, the records, and for every record the ids of the
bank nodes that support it (`evidence`) and a per-signal score breakdown (`score`: vector,
keyword, graph, fused) that says why it was returned. Records whose embeddings have cosine >= 0.95
with a better-ranked one collapse into it (`duplicates`). Field names follow the reference implementation's tool results.

"How to do it" lives in `get_routine_skill` / `search_activities` / `search_patterns`; "which
object and where" in `search_objects` / `get_object_history` / `get_state_at_time`; `search`
dispatches one query to every store.
"""

from __future__ import annotations

import json
import math
from collections import Counter

import numpy as np

from memora_graph.consolidate.task_records import TASK_SOURCES  # Routine / Preference rows of the task memory
from memora_graph.perceive.vocab import PLACE_NAMES
from memora_graph.records import segment_id
from memora_graph.retrieve.args import (
    HistoryArgs, ObjectArgs, PreferenceArgs, QueryArgs, RoutineArgs, SearchArgs, StateArgs, VideoArgs,
)
from memora_graph.retrieve.registry import Family, Reply, register_family, tool
from memora_graph.retrieve.results import (
    Action, ActivitiesResult, ActivityRecord, ObjectHistoryResult, ObjectRecord, ObjectsResult, PatternRecord,
    PatternsResult, PlaceRecord, PlacesResult, PreferenceRecord, PreferencesResult, RoutineRecord, RoutinesResult,
    ObjectCount, Score, SearchResult, StateAtTimeResult, VideoActivitiesResult, VisibleObject, PREFERENCE_FIELDS,
)
from memora_graph.retrieve.search import DEFAULT_TOP_K, MAX_TOP_K, Candidate, dedup, fuse, rank
from memora_graph.retrieve.view import MemoryView, ToolError
from memora_graph.text import index_stem, index_tokens

register_family(Family("memora", "MEMORA typed stores", MemoryView.open))

ACTION_WORDS = frozenset(index_stem(w) for w in (
    "wash", "cut", "cook", "stir", "mix", "pour", "put", "take", "open", "close", "rinse", "dry", "peel", "fry", "boil",
    "clean", "prepare", "make", "chop", "slice", "fill", "empty", "turn", "scrub", "wipe", "bake", "heat", "spread",
))
PREFERENCE_WORDS = frozenset(index_stem(w) for w in (
    "prefer", "preference", "usually", "typically", "often", "always", "habit", "tend", "like", "favorite", "favourite",
    "store", "keep", "routine",
))


def _k(top_k: int | None, default: int = DEFAULT_TOP_K) -> int:
    k = default if top_k is None else int(top_k)
    if k < 1:
        raise ToolError("top_k must be at least 1")
    return min(k, MAX_TOP_K)


def _query(query: str | None, name: str = "query") -> str:
    q = (query or "").strip()
    if not q:
        raise ToolError(f"{name} must be a non-empty string")
    return q


def _listed(view: MemoryView, query: str, top_k: int | None, find) -> Reply:
    """A one-store search tool's reply: the records `find(view, query, query vector, k)` ranks."""
    query, k = _query(query), _k(top_k)
    return Reply({"query": query, "top_k": k}, results=find(view, query, view.embed(query), k))


def _score(c: Candidate) -> Score:
    return Score(**c.breakdown())


def _place_name(location: str) -> str:
    return PLACE_NAMES.get(location, (location or "").replace("_", " "))


def grounded_entities(view: MemoryView, query: str) -> set[str]:
    """Entity ids whose kind or name shares a word with the query ("wash the bowl" -> bowls)."""
    index = view.__dict__.get("_entity_words")
    if index is None:
        index = {}
        for eid, e in view.entities.items():
            for t in set(index_tokens(f"{e['kind']} {e['name']}".replace("_", " "))):
                index.setdefault(t, set()).add(eid)
        view.__dict__["_entity_words"] = index
    out: set[str] = set()
    for t in index_tokens(query):
        out |= index.get(t, set())
    return out


def _hybrid(view: MemoryView, table: str, query: str, q: np.ndarray, pool: int) -> dict[str, Candidate]:
    cfg = view.config
    vec_hits = view.knn(table, q, pool)
    kw_hits = view.keyword(table, query, pool)
    vt = view.vectors(table) if cfg.vector == "numpy" or kw_hits else None
    cands = fuse(vec_hits, kw_hits, vt, q, cfg)
    if cfg.vector != "numpy":  # exact cosine for every candidate, whatever ranked it
        vt = view.vectors(table)
        for c in cands.values():
            v = vt.vec(c.id)
            if v is not None and c.vector_rank is None:
                c.similarity = float(v @ q)
    return cands


def _finish(view: MemoryView, table: str, cands: dict[str, Candidate], top_k: int) -> list[Candidate]:
    cfg = view.config
    ranked = rank(cands, cfg)
    return dedup(ranked, view.vectors(table), cfg.dedup_cosine, top_k)


# -- unified ---------------------------------------------------------------------------------------
CATEGORIES = ("objects", "activities", "places", "patterns")
_ALIASES = {"environment": "places", "objects": "objects", "object": "objects", "activities": "activities",
            "activity": "activities", "places": "places", "place": "places", "patterns": "patterns", "pattern": "patterns"}


@tool("search", args=SearchArgs, result=SearchResult, store="unified search",
      description="Search every memory store at once (objects, activities, places, patterns) and return the top few "
                  "records of each.")
def search(view: MemoryView, query: str, category: str | None = None, top_k_per_category: int = 3) -> Reply:
    """One query over every store (objects, activities, places, patterns), top few per store.
    Action queries get twice the activities; preference queries get three times the patterns."""
    query, k = _query(query), _k(top_k_per_category, 3)
    cats = CATEGORIES
    if category:
        if category.lower() not in _ALIASES:
            raise ToolError(f"category must be one of: {', '.join(CATEGORIES)}")
        cats = (_ALIASES[category.lower()],)
    words = set(index_tokens(query))
    k_of = {c: k for c in cats}
    routing = []
    if words & ACTION_WORDS and "activities" in k_of:
        k_of["activities"] = min(2 * k, MAX_TOP_K)
        routing.append("action query: 2x activities")
    if words & PREFERENCE_WORDS and "patterns" in k_of:
        k_of["patterns"] = min(3 * k, MAX_TOP_K)
        routing.append("preference query: 3x patterns")
    q = view.embed(query)
    run = {"objects": _search_objects, "activities": _search_activities, "places": _search_places, "patterns": _search_patterns}
    body = {c: run[c](view, query, q, k_of[c]) for c in cats}
    return Reply({"query": query, "category": category, "top_k_per_category": k},
                 routing=routing, **body)


# -- objects -------------------------------------------------------------------------------------
def _object_record(view: MemoryView, c: Candidate) -> ObjectRecord:
    e = view.entities[c.id]
    places = view.graph.entity_places.get(c.id, Counter())
    used = view.graph.used_with(c.id, 5)
    visual = {k: e[k] for k in ("color", "material", "size") if e[k]}
    first_seg = segment_id(e["first_video"], int(e["first_turn"])) if e["first_video"] else None
    last_seg = segment_id(e["last_video"], int(e["last_turn"])) if e["last_video"] else None
    return ObjectRecord(**{
        "object_id": e["object_id"], "entity_id": e["id"], "name": e["name"], "kind": e["kind"], "category": e["category"],
        "visual_properties": visual,
        "spatial_info": {"location": e["location"], "place": _place_name(e["location"]), "is_fixture": e["is_fixture"]},
        "state": {"current_state": e["state"], "held_by": e["held_by"] or None, "status": e["status"]},
        "places": [{"location": loc, "place": _place_name(loc), "observations": n}
                   for loc, n in sorted(places.items(), key=lambda kv: (-kv[1], kv[0]))[:3]],
        "used_with": [{"entity_id": u, "name": view.entities[u]["name"] if u in view.entities else u, "segments": n}
                      for u, n in used],
        "time_seen_seconds": {"first": {"video": e["first_video"], "t": e["first_seen"]},
                              "last": {"video": e["last_video"], "t": e["last_seen"]}},
        "n_observations": e["n_observations"],
        "similarity": round(c.similarity, 4),
        "score": _score(c),
        "evidence": [x for x in (e["id"], first_seg, last_seg) if x],
        "duplicates": c.duplicates or None,
    })


@tool("search_objects", args=ObjectArgs, result=ObjectsResult, store="Entity",
      description="Find objects the person has: identity, colour/material, current state and place, the places it "
                  "was seen at and the objects used with it.")
def search_objects(view: MemoryView, query: str, top_k: int = DEFAULT_TOP_K) -> Reply:
    """Objects (entity memory) matching a description: identity, attributes, current state and
    place, the places it was seen at and the objects used with it."""
    return _listed(view, query, top_k, _search_objects)


def _search_objects(view: MemoryView, query: str, q: np.ndarray, k: int) -> list[ObjectRecord]:
    cands = _hybrid(view, "entity", query, q, view.config.pool)
    active, top = view.active_entities, view.max_observations
    for c in cands.values():
        n = (view.entities.get(c.id) or {}).get("n_observations") or 0
        c.graph = np.log1p(n) / np.log1p(top) if top else None  # usage degree: HAS_STATE edges
    cands = {i: c for i, c in cands.items() if i in active}
    return [_object_record(view, c) for c in _finish(view, "entity", cands, k)]


# -- activities ----------------------------------------------------------------------------------
def _steps(raw: str) -> list[dict]:
    try:
        steps = json.loads(raw or "[]")
    except json.JSONDecodeError:
        return []
    return [{"t": f"{s.get('timestamp', 0):.1f}-{min(s.get('end', 0), 99.9):.1f}s", "action": s.get("action", ""),
             "object": s.get("object", ""), "narration": s.get("narration", "")} for s in steps]


def _environment(view: MemoryView, location: str) -> str:
    p = view.places.get(location)
    zones = ", ".join(p["zones"][:8]) if p and p["zones"] else ""
    text = _place_name(location) + (f" (zones: {zones})" if zones else "")
    return text[:150]


def _neighbour(seg: dict, delta: int) -> str:
    return segment_id(seg["video"], int(seg["turn"]) + delta)


def _activity_record(view: MemoryView, seg: dict, rows: dict[str, dict], c: Candidate | None) -> ActivityRecord:
    prev, nxt = rows.get(_neighbour(seg, -1)), rows.get(_neighbour(seg, 1))
    scene = sorted({view.entities[e]["name"] for e in view.graph.segment_entities.get(seg["id"], ()) if e in view.entities})
    rec = {
        "segment_id": seg["id"], "source_video": seg["video"], "turn_id": seg["turn"],
        "time": {"start": seg["t_start"], "end": seg["t_end"]},
        "summary": seg["summary"], "detailed_narrative": seg["narrative"], "action_breakdown": _steps(seg["action_breakdown"]),
        "previous_action": (prev["summary"][:100] if prev else None), "next_action": (nxt["summary"][:100] if nxt else None),
        "scene_objects": scene[:10], "environment": _environment(view, seg["location"]),
    }
    if c is not None:
        rec.update({"similarity": round(c.similarity, 4), "score": _score(c), "duplicates": c.duplicates or None})
    rec["evidence"] = [seg["id"]]
    return ActivityRecord(**rec)


@tool("search_activities", args=QueryArgs, result=ActivitiesResult, store="Activity",
      description="Find past episodes (10 s activity records): what was done, step by step, with the actions "
                  "before and after.")
def search_activities(view: MemoryView, query: str, top_k: int = DEFAULT_TOP_K) -> Reply:
    """Episodes (10 s activity records) matching a query, with what came before and after."""
    return _listed(view, query, top_k, _search_activities)


def _search_activities(view: MemoryView, query: str, q: np.ndarray, k: int) -> list[ActivityRecord]:
    cands = _hybrid(view, "segment", query, q, view.config.pool)
    grounded = grounded_entities(view, query)
    if grounded:  # share of the query's objects (by kind) that the segment observed
        kinds = {view.entities[e]["kind"] for e in grounded}
        entities = view.entities
        for c, observed in zip(cands.values(), view.graph.segment_entities.many(list(cands))):
            seen = {entities[e]["kind"] for e in observed or () if e in entities}
            c.graph = len(seen & kinds) / len(kinds)
    kept = _finish(view, "segment", cands, k)
    ids = [c.id for c in kept]
    wanted = set(ids)
    for c in kept:
        video, turn = c.id.rsplit("#t", 1)
        wanted |= {segment_id(video, int(turn) - 1), segment_id(video, int(turn) + 1)}
    rows = {r["id"]: r for r in view.by_id("_tool_segment", sorted(wanted))}
    return [_activity_record(view, rows[c.id], rows, c) for c in kept if c.id in rows]


@tool("get_video_activities", args=VideoArgs, result=VideoActivitiesResult, store="Activity",
      description="One video's activity log in time order: the moments about an object or action (query), or the "
                  "whole video evenly sampled, with the objects handled most in it.")
def get_video_activities(view: MemoryView, video: str, query: str = "", top_k: int = MAX_TOP_K) -> Reply:
    """The activity records of one video, in time order: those closest to `query` (vector and the
    objects it names), or evenly spaced over the video; with the objects handled in most of its
    segments."""
    k = _k(top_k, MAX_TOP_K)
    if video not in view.videos:
        raise ToolError(f"no video {video!r} in {view.participant}'s memory (has: {', '.join(sorted(view.videos))})")
    query = (query or "").strip()
    rows = view.fetch("_tool_video_segments", video=video)
    by_id = {r["id"]: r for r in rows}
    if query and rows:
        q = view.embed(query)
        vt = view.vectors("segment")
        grounded = grounded_entities(view, query)
        kinds = {view.entities[e]["kind"] for e in grounded}

        def relevance(r: dict) -> float:
            v = vt.vec(r["id"])
            sim = float(v @ q) if v is not None else 0.0
            seen = {view.entities[e]["kind"] for e in view.graph.segment_entities.get(r["id"], ()) if e in view.entities}
            return sim + (len(seen & kinds) / len(kinds) if kinds else 0.0)

        chosen = sorted(sorted(rows, key=lambda r: (-relevance(r), r["turn"]))[:k], key=lambda r: r["turn"])
    else:
        step = max(1, -(-len(rows) // k))
        chosen = rows[::step][:k]
    counts: Counter[str] = Counter()
    for r in rows:
        for e in view.graph.segment_entities.get(r["id"], ()):
            counts[e] += 1
    objects = [ObjectCount(name=view.entities[e]["name"], kind=view.entities[e]["kind"], segments=n)
               for e, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])) if e in view.entities][:15]
    info = view.videos[video]
    return Reply({"video": video, "query": query, "top_k": k},
                 video=video, duration=info.get("duration"), segments=len(rows), objects=objects,
                     results=[_activity_record(view, r, by_id, None) for r in chosen])


# -- places ----------------------------------------------------------------------------------------
@tool("search_environment", args=QueryArgs, result=PlacesResult, store="Environment", advertised=False,
      description="Find places (kitchen areas) with their zones, features and the objects there now.")
def search_environment(view: MemoryView, query: str, top_k: int = DEFAULT_TOP_K) -> Reply:
    """Places (environment memory): zones, features, how much they are used, what is there now."""
    return _listed(view, query, top_k, _search_places)


def _search_places(view: MemoryView, query: str, q: np.ndarray, k: int) -> list[PlaceRecord]:
    cands = _hybrid(view, "place", query, q, view.config.pool)
    by_id = {p["id"]: p for p in view.places.values()}
    top = max((p["turn_count"] or 0 for p in by_id.values()), default=0)
    for c in cands.values():
        if c.id in by_id and top:
            c.graph = (by_id[c.id]["turn_count"] or 0) / top
    out = []
    for c in _finish(view, "place", cands, k):
        p = by_id.get(c.id)
        if p is None:
            continue
        here = _objects_at(view).get(p["location_id"], ())
        out.append(PlaceRecord(
            place_id=p["location_id"], name=p["name"], zones=p["zones"] or [], features=p["features"] or [],
            turns=p["turn_count"], first_seen={"video": p["first_video"], "t": p["first_seen"]},
            last_seen={"video": p["last_video"], "t": p["last_seen"]},
            objects_here=[e["name"] for e in here[:10]],
            similarity=round(c.similarity, 4), score=_score(c), evidence=[p["id"]], duplicates=c.duplicates or None,
        ))
    return out


def _objects_at(view: MemoryView) -> dict[str, list[dict]]:
    """location -> the active entities there, most observed first (ties by id): computed once per
    view (the entities change only with a remembered moment, which drops it: view.absorb), not a
    scan of every entity per place answered."""
    at = view.__dict__.get("_objects_at")
    if at is None:
        at = {}
        for e in view.entities.values():
            if e["status"] == "active":
                at.setdefault(e["location"], []).append(e)
        for group in at.values():
            group.sort(key=lambda e: (-(e["n_observations"] or 0), e["id"]))
        view.__dict__["_objects_at"] = at
    return at


# -- inferred knowledge ------------------------------------------------------------------------------
def _links(view: MemoryView) -> dict[str, set[str]]:
    links = view.__dict__.get("_links")
    if links is None:
        links = {}
        for r in view.fetch("_tool_inferred_links"):
            links.setdefault(r["id"], set()).add(r["entity"])
        view.__dict__["_links"] = links
    return links


def _inferred_graph(view: MemoryView, cands: dict[str, Candidate], query: str) -> None:
    """Graph signal for routines / preferences: share of the query's objects they use (USES / ABOUT)."""
    grounded = grounded_entities(view, query)
    if not grounded:
        return
    kinds = {view.entities[e]["kind"] for e in grounded}
    used = _link_kinds(view)
    for c in cands.values():
        c.graph = len(used.get(c.id, frozenset()) & kinds) / len(kinds)


def _link_kinds(view: MemoryView) -> dict[str, frozenset[str]]:
    """routine / preference id -> the kinds of the entities it uses or is about, computed once per
    view (a preference links up to thousands of entity records at 1,000 h: reading their kinds per
    candidate cost ~35 ms a search). Dropped with the links (`reload_inferred`) and with the
    entities (`absorb`)."""
    kinds = view.__dict__.get("_link_kinds")
    if kinds is None:
        ents = view.entities
        kinds = {rid: frozenset(ents[e]["kind"] for e in linked if e in ents) for rid, linked in _links(view).items()}
        view.__dict__["_link_kinds"] = kinds
    return kinds


def _routine_record(view: MemoryView, r: dict, c: Candidate | None) -> RoutineRecord:
    steps = view.routine_detail(r["id"]).get("steps")
    if not (isinstance(steps, list) and all(isinstance(x, dict) and isinstance(x.get("verb"), str) for x in steps)):
        steps = None  # a processor that recorded no structured steps (or something else under that key)
    rec = {
        "routine_id": r["id"], "goal": r["goal"], "activity_type": r["activity_type"],
        "canonical_steps": [{"action": s} for s in r["canonical_steps"]],
        "steps": [Action(verb=x["verb"], noun=str(x.get("noun") or ""), place=x.get("place") or None)
                  for x in steps] if steps else None,
        "key_objects": [{"object": o} for o in r["key_objects"]],
        "supporting_episodes": r["supporting_episodes"], "source_videos": r["source_videos"], "count": r["count"],
        "confidence": r["confidence"],
        "source": "routine_skill" if r["source"] == "routine_skill" else "procedure_template",
        "kind": r["source"], "processor": r["processor"],
    }
    if c is not None:
        rec.update({"similarity": round(c.similarity, 4), "score": _score(c), "duplicates": c.duplicates or None})
    rec["evidence"] = [r["id"], *r["supporting_episodes"]]
    return RoutineRecord(**rec)


def _preference_fields(detail: dict) -> dict:
    """The structured fields consolidation stored with a preference (object and preferred location,
    trigger and next action, use and what follows, the alternatives), as the record's fields."""
    out = {}
    for key in PREFERENCE_FIELDS:
        value = detail.get(key)
        if key == "alternatives":
            ok = isinstance(value, dict) and value and all(isinstance(n, int) for n in value.values())
        elif key in ("trigger_step", "next_step"):
            ok = isinstance(value, dict) and isinstance(value.get("verb"), str)
        elif key == "actions":
            ok = isinstance(value, list) and bool(value) and all(isinstance(a, dict) and isinstance(a.get("verb"), str)
                                                                  for a in value)
        elif key in ("trigger_count", "total"):
            ok = isinstance(value, int) and not isinstance(value, bool)
        else:
            ok = isinstance(value, str) and value != ""
        if ok:
            out[key] = _drop_blank(value)
    return out


def _drop_blank(value):
    """A stored step's empty fields ("place": "") are absent, not empty strings."""
    if isinstance(value, dict) and "verb" in value:
        return {k: v for k, v in value.items() if v != ""}
    if isinstance(value, list):
        return [_drop_blank(v) for v in value]
    return value


def _preference_record(view: MemoryView, p: dict, c: Candidate | None) -> PreferenceRecord:
    rec = {
        "preference_id": p["id"], "preference": p["statement"], "subtype": p["subtype"], "keywords": p["keywords"],
        "objects": p["objects"], "context": p["context"], **_preference_fields(p["detail"]),
        "evidence_summary": p["evidence_summary"],
        "confidence": p["confidence"], "count": p["count"], "supporting_episodes": p["supporting_episodes"],
        "source_videos": p["source_videos"],
        "source": "generated_preference" if p["source"] == "enrichment" else "consolidated_preference",
        "processor": p["processor"],
    }
    if c is not None:
        rec.update({"similarity": round(c.similarity, 4), "score": _score(c), "duplicates": c.duplicates or None})
    else:
        rec["similarity"] = -1
    rec["evidence"] = [p["id"], *p["supporting_episodes"]]
    return PreferenceRecord(**rec)


@tool("get_routine_skill", args=RoutineArgs, result=RoutinesResult, store="Inferred",
      description="Routine skills for a goal: canonical steps, key objects and the episodes they come from. Call this "
                  "first when planning.")
def get_routine_skill(view: MemoryView, goal_query: str, top_k: int = 3) -> Reply:
    """Routine skills (goal, canonical steps, key objects, supporting episodes) for a goal."""
    query, k = _query(goal_query, "goal_query"), _k(top_k, 3)
    args = {"goal_query": query, "top_k": k}
    if not view.routines:
        return Reply(args, routines=[],
                     error="no routine skills in this memory (a MEMORA-Episodic bank, or too little repetition)")
    return Reply(args, routines=_search_routines(view, query, view.embed(query), k))


TASK_EXTRA = 5  # task-level records a routine or preference search adds after its top k (see _with_tasks)


def _task_ids(view: MemoryView, table: str, rows: dict) -> frozenset[str]:
    """The ids of the task memory's rows of a table (read each call: live memory adds rows)."""
    return frozenset(i for i, r in rows.items() if r.get("source") in TASK_SOURCES)


def _reranked(cands: dict[str, Candidate], pool: int) -> dict[str, Candidate]:
    """Candidates of one kind with their vector and keyword ranks counted among themselves, cut to
    `pool` per signal: as if the other kind's rows were not in the table."""
    for attr in ("vector_rank", "keyword_rank"):
        for n, c in enumerate(sorted((c for c in cands.values() if getattr(c, attr)), key=lambda c: getattr(c, attr)), 1):
            setattr(c, attr, n if n <= pool else None)
    return {i: c for i, c in cands.items() if c.vector_rank or c.keyword_rank}


def _with_tasks(view: MemoryView, table: str, rows: dict, query: str, q: np.ndarray, k: int) -> list:
    """The top k of the other records as before, then up to TASK_EXTRA task-level records (a
    recurring task's stages, how tasks are done): they answer how a task is organised, and
    ranked among the rest they would push out the habits and storage places a search answered
    with before. The candidate pool is widened by the task rows and each kind is ranked among
    itself, so the task rows take no place in the other records' pool or ranks."""
    pool = view.config.pool
    task_ids = _task_ids(view, table, rows)
    cands = _hybrid(view, table, query, q, pool + len(task_ids))
    _inferred_graph(view, cands, query)
    task = _reranked({i: c for i, c in cands.items() if i in task_ids}, pool)
    other = _reranked({i: c for i, c in cands.items() if i not in task_ids}, pool)
    out = _finish(view, table, other, k)
    if task:
        out += _finish(view, table, task, min(k, TASK_EXTRA))
    return out


def _search_routines(view: MemoryView, query: str, q: np.ndarray, k: int) -> list[RoutineRecord]:
    return [_routine_record(view, view.routines[c.id], c) for c in _with_tasks(view, "routine", view.routines, query, q, k)
            if c.id in view.routines]


@tool("get_preferences", args=PreferenceArgs, result=PreferencesResult, store="Inferred",
      description="The person's preferences (where things are kept, habits, tool choices) relevant to a query, with "
                  "their evidence.")
def get_preferences(view: MemoryView, query: str = "", top_k: int = 5) -> Reply:
    """Preferences (storage, habit, workflow, generated) by similarity to a query, or by
    confidence when the query is empty."""
    query, k = (query or "").strip(), _k(top_k, 5)
    args = {"query": query, "top_k": k}
    if not query:
        ranked = sorted(view.preferences.values(), key=lambda p: (-p["confidence"], -p["count"], p["id"]))[:k]
        return Reply(args, preferences=[_preference_record(view, p, None) for p in ranked])
    return Reply(args, preferences=_search_preferences(view, query, view.embed(query), k))


def _search_preferences(view: MemoryView, query: str, q: np.ndarray, k: int) -> list[PreferenceRecord]:
    return [_preference_record(view, view.preferences[c.id], c)
            for c in _with_tasks(view, "preference", view.preferences, query, q, k) if c.id in view.preferences]


@tool("search_patterns", args=QueryArgs, result=PatternsResult, store="Inferred",
      description="Find consolidated patterns: storage preferences, habits, workflows, routines and recurring action "
                  "sequences.")
def search_patterns(view: MemoryView, query: str, top_k: int = DEFAULT_TOP_K) -> Reply:
    """Consolidated patterns: preferences, habits, workflows, routines and recurring sequences."""
    return _listed(view, query, top_k, _search_patterns)


def _pattern(rec: RoutineRecord | PreferenceRecord) -> PatternRecord:
    if isinstance(rec, RoutineRecord):
        category = {"routine_skill": "routine", "task_routine": "task_routine"}.get(rec.kind, "action_sequence")
        pid = rec.routine_id
    else:
        category, pid = rec.subtype, rec.preference_id
    return PatternRecord(category=category, pattern_id=pid, description=rec.text(), source=rec.source,
                         supporting_episodes=rec.supporting_episodes[:3], confidence=rec.confidence, count=rec.count,
                         similarity=rec.similarity, score=rec.score, evidence=rec.evidence, duplicates=rec.duplicates)


def _search_patterns(view: MemoryView, query: str, q: np.ndarray, k: int) -> list[PatternRecord]:
    if not view.routines and not view.preferences:
        return []
    merged = [(_pattern(r), r.score.fused) for r in _search_routines(view, query, q, k)] + \
             [(_pattern(p), p.score.fused) for p in _search_preferences(view, query, q, k)]
    merged.sort(key=lambda x: (-x[1], -x[0].similarity, x[0].pattern_id))
    return [m for m, _ in merged[:k]]


# -- object history and state ------------------------------------------------------------------------
class _ObjectNames:
    """What `resolve_object` matches a reference against, read from every entity once per view (a
    scan of every entity record per call cost ~13 ms at 1,000 h): the entities by id, object id,
    kind and name (lower case), by object id and kind for the reference as a slug, and each
    entity's (id, object id, name in lower case) for the substring match."""

    def __init__(self, ents: dict[str, dict]):
        exact: dict[str, list[str]] = {}
        exact_slug: dict[str, list[str]] = {}
        self.rows = [(i, e["object_id"], e["name"].lower()) for i, e in ents.items()]
        for i, e in ents.items():
            for key in {i.lower(), e["object_id"], e["kind"], e["name"].lower()}:
                exact.setdefault(key, []).append(i)
            for key in {e["object_id"], e["kind"]}:
                exact_slug.setdefault(key, []).append(i)
        # tuples of strings: the cyclic collector stops walking them (a view lives long)
        self.exact = {k: tuple(v) for k, v in exact.items()}
        self.exact_slug = {k: tuple(v) for k, v in exact_slug.items()}


def _object_names(view: MemoryView) -> _ObjectNames:
    names = view.__dict__.get("_object_names")
    if names is None:
        names = view.__dict__["_object_names"] = _ObjectNames(view.entities)
    return names


def resolve_object(view: MemoryView, text: str) -> tuple[list[str], str]:
    """Entity ids for an object reference, best first, and how they matched: exact (id, object
    id, kind or name), substring, or embedding (cosine > 0.6 over entity identities)."""
    t = text.strip().lower()
    slug = t.replace(" ", "_")
    ents = view.entities

    def order(ids):
        return sorted(ids, key=lambda i: (ents[i]["status"] != "active", -(ents[i]["n_observations"] or 0), i))

    names = _object_names(view)
    exact = {*names.exact.get(t, ()), *names.exact_slug.get(slug, ())}
    if exact:
        return order(exact), "exact"
    sub = [i for i, object_id, name in names.rows if slug in object_id or t in name]
    if sub:
        return order(sub), "substring"
    q = view.embed(text)
    hits = [(i, s) for i, s in view.vectors("entity").topk(q, 3) if s > 0.6]
    return [i for i, _ in hits], "embedding"


@tool("get_object_history", args=HistoryArgs, result=ObjectHistoryResult, store="Entity",
      description="The state history of one object across videos: every state and location, moves, first and last "
                  "seen.")
def get_object_history(view: MemoryView, object_query: str, max_entries: int = 60) -> Reply:
    """One object's state history across videos: states, locations, moves, first / last seen."""
    query = _query(object_query, "object_query")
    args = {"object_query": query, "max_entries": max_entries}
    ids, how = resolve_object(view, query)
    if not ids:
        return Reply(args, found=False,
                     error=f"no object matching {query!r}; try search_objects first")
    e = view.entities[ids[0]]
    # The summary, the last moves and the ids of the last entries come from the persisted history
    # index (retrieve/history.py: a bounded read, the entries shown included), or from one thin
    # columnar outline of the whole history and the entries shown read whole, each by key.
    h = view.history_parts(e["id"], max_entries)
    tail = h.tail if h.tail is not None else view.by_id("_tool_history_entry", h.tail_ids)
    shown = []
    for r in tail:
        shown.append({"event_id": r["id"], "segment_id": segment_id(r["video"], int(r["turn"])), "video": r["video"],
                      "turn_id": r["turn"], "time_seconds": r["t"], "state": r["state"], "location": r["location"],
                      "zone": r["zone"] or None, "held_by": r["held_by"] or None, "relative_to": r["relative_to"] or None,
                      "relation": r["relation"] or None, "action": r["action"] or None, "narration": r["narration"],
                      "editor_op": r["op"]})
    return Reply(
        args, found=True, object_id=e["object_id"], entity_id=e["id"], name=e["name"],
        match_type=how, status=e["status"], current_state=e["state"], current_location=e["location"],
        all_states_observed=h.states, all_locations_observed=h.locations,
        videos=h.videos, location_transitions=h.transitions,
        state_history=shown, history_total=h.total, history_shown=len(shown),
        first_seen={"video": e["first_video"], "t": e["first_seen"]}, last_seen={"video": e["last_video"], "t": e["last_seen"]},
        other_matches=[{"entity_id": i, "name": view.entities[i]["name"], "status": view.entities[i]["status"]} for i in ids[1:6]],
        evidence=[e["id"], *h.segments],
    )


@tool("get_state_at_time", args=StateArgs, result=StateAtTimeResult, store="Activity",
      description="What was where, and in which state, at a time of a video (from the state history), with the "
                  "activity and place at that moment.")
def get_state_at_time(view: MemoryView, time_seconds: float, video: str | None = None,
                      window: float = 60.0) -> Reply:
    """What was where, in which state, at `time_seconds` of a video, from the state history: every
    object seen in the video by then and again after (or within `window` s before), each in its
    last recorded state at that time."""
    try:
        t, window = float(time_seconds), float(window)
    except (TypeError, ValueError) as exc:
        raise ToolError("time_seconds and window must be numbers of seconds") from exc
    if not (math.isfinite(t) and t >= 0 and math.isfinite(window) and window >= 0):
        raise ToolError(f"time_seconds and window must be finite numbers of seconds, 0 or more (got {time_seconds!r}, "
                        f"{window!r})")
    videos = sorted(view.videos)
    if video is None:
        if len(videos) != 1:
            raise ToolError(f"get_state_at_time needs `video` (one of: {', '.join(videos)})")
        video = videos[0]
    if video not in view.videos:
        raise ToolError(f"no video {video!r} in {view.participant}'s memory (has: {', '.join(videos)})")
    args = {"time_seconds": t, "video": video, "window": window}
    rows = view.fetch("_tool_video_events", video=video)
    first: dict[str, float] = {}
    last_seen: dict[str, float] = {}
    state: dict[str, dict] = {}
    for r in rows:  # ordered by t, ord
        first.setdefault(r["entity"], r["t"])
        last_seen[r["entity"]] = r["t"]
        if r["t"] <= t:
            state[r["entity"]] = r
    visible = []
    for ent, r in state.items():
        if not (first[ent] <= t <= last_seen[ent] + window):
            continue
        info = view.entities.get(ent, {})
        visible.append(VisibleObject(**{
            "entity_id": ent, "object_id": info.get("object_id"), "name": info.get("name", ent),
            "state": r["state"], "location": r["location"], "zone": r["zone"] or None, "held_by": r["held_by"] or None,
            "relative_to": r["relative_to"] or None, "relation": r["relation"] or None,
            "since_seconds": r["t"], "last_action": r["action"] or None, "event_id": r["id"],
            "segment_id": segment_id(video, int(r["turn"])),
        }))
    visible.sort(key=lambda v: (-v.since_seconds, v.entity_id))
    turn = int(t // 10)
    seg_ids = [segment_id(video, turn)]
    segs = {s["id"]: s for s in view.by_id("_tool_segment", seg_ids)}
    seg = segs.get(seg_ids[0])
    return Reply(
        args, segment_id=seg["id"] if seg else None,
        current_activity=seg["summary"] if seg else None,
        environment=_environment(view, seg["location"]) if seg else None, visible_objects=visible,
        evidence=([seg["id"]] if seg else []) + [v.event_id for v in visible],
    )


__all__ = [
    "get_object_history", "get_preferences", "get_routine_skill", "get_state_at_time", "resolve_object", "search",
    "search_activities", "search_environment", "search_objects", "search_patterns",
]

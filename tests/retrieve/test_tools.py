"""The retrieval tools: scoping, state at a time, dedup, determinism, registry, CLI, benchmark."""

from __future__ import annotations

import json
import random
import re

import numpy as np
import polars as pl
import pytest
from click.testing import CliRunner

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.retrieve import MemoryView, ToolError, call_tool, tool_names, tool_schemas
from memora_graph.retrieve.search import Candidate, VectorTable, dedup
from memora_graph.store import Store

SMALL = ("P09", "P37")
_ID = re.compile(r"^P\d{2}[_:]")

# Every table the tools read, copied from each participant's database into one merged database:
# the participant filter in the queries, not the file boundary, must keep memories apart.
_NODES = {
    "Participant": "MATCH (n:Participant) RETURN n.*", "Video": "MATCH (n:Video) RETURN n.*",
    "Segment": "MATCH (n:Segment) RETURN n.*", "Place": "MATCH (n:Place) RETURN n.*",
    "Entity": "MATCH (n:Entity) RETURN n.*", "StateEvent": "MATCH (n:StateEvent) RETURN n.*",
    "Routine": "MATCH (n:Routine) RETURN n.*", "Preference": "MATCH (n:Preference) RETURN n.*",
}
_RELS = [
    ("HAS_STATE", None, None, "MATCH (a)-[r:HAS_STATE]->(b) RETURN a.id AS `from`, b.id AS `to`, r.ord AS ord"),
    ("OBSERVED_IN", None, None, "MATCH (a)-[r:OBSERVED_IN]->(b) RETURN a.id AS `from`, b.id AS `to`"),
    ("USES", None, None, "MATCH (a)-[r:USES]->(b) RETURN a.id AS `from`, b.id AS `to`"),
    ("ABOUT", None, None, "MATCH (a)-[r:ABOUT]->(b) RETURN a.id AS `from`, b.id AS `to`"),
    ("SUPPORTED_BY", "Routine", "Segment",
     "MATCH (a:Routine)-[r:SUPPORTED_BY]->(b:Segment) RETURN a.id AS `from`, b.id AS `to`"),
    ("SUPPORTED_BY", "Preference", "Segment",
     "MATCH (a:Preference)-[r:SUPPORTED_BY]->(b:Segment) RETURN a.id AS `from`, b.id AS `to`"),
]


@pytest.fixture(scope="module")
def merged(small_bank, tmp_path_factory, embedder):
    path, _ = small_bank
    bank = Bank(path)
    dest = Store(tmp_path_factory.mktemp("merged") / "P00.kuzu", read_only=False)
    dest.apply_schema()
    for p in SMALL:
        with bank.open(p) as src:
            frames = {t: src.query(q) for t, q in _NODES.items()}
            rels = [(t, f, to, src.query(q)) for t, f, to, q in _RELS]
        with dest.transaction():
            for table, frame in frames.items():
                dest.copy(table, frame.rename({c: c.removeprefix("n.") for c in frame.columns}))
            for table, f, to, frame in rels:
                dest.copy(table, frame, from_table=f, to_table=to)
    dest.ensure_indexes()
    yield dest
    dest.close()


def _ids(obj) -> set[str]:
    out = set()
    if isinstance(obj, dict):
        for v in obj.values():
            out |= _ids(v)
    elif isinstance(obj, list):
        for v in obj:
            out |= _ids(v)
    elif isinstance(obj, str) and _ID.match(obj):
        out.add(obj)
    return out


def _calls(view: MemoryView, words: list[str], videos: list[str]) -> list[tuple[str, dict]]:
    calls = []
    for w in words:
        calls += [("search", {"query": w}), ("search_objects", {"query": w}), ("search_activities", {"query": w}),
                  ("search_patterns", {"query": w}), ("get_routine_skill", {"goal_query": w}),
                  ("get_preferences", {"query": w}), ("get_object_history", {"object_query": w}),
                  ("search_environment", {"query": w})]
    calls.append(("get_preferences", {"query": ""}))
    calls += [("get_state_at_time", {"time_seconds": t, "video": v}) for v in videos for t in (15.0, 95.0)]
    return calls


@pytest.mark.parametrize("recipe", ["inprocess", "fts", "kuzu"])
def test_no_tool_returns_another_participants_records(merged, embedder, recipe):
    rng = random.Random(7)
    names = {p: sorted(r["name"] for r in MemoryView(merged, p, embedder).entities.values()) for p in SMALL}
    for a, b in ((SMALL[0], SMALL[1]), (SMALL[1], SMALL[0])):
        view = MemoryView(merged, a, embedder, config=recipe)
        # the other participant's own object words, so a leak would be the best match
        words = rng.sample(names[b], 3) + rng.sample(names[a], 2) + ["wash the dishes", "where is the knife kept"]
        videos = sorted(view.videos)
        assert videos and all(v.startswith(a) for v in videos)
        seen = set()
        for name, args in _calls(view, words, videos[:2]):
            result = call_tool(view, name, args)
            ids = _ids(result.as_json())
            leaked = {i for i in ids if not i.startswith(a)}
            assert not leaked, f"{name}({args}) for {a} returned {sorted(leaked)[:5]}"
            seen |= ids
        assert any("#t" in i for i in seen) and any(":" in i for i in seen), "the calls returned records at all"
        other_video = sorted(MemoryView(merged, b, embedder).videos)[0]
        with pytest.raises(ToolError, match="no video"):
            call_tool(view, "get_state_at_time", {"time_seconds": 10, "video": other_video})


def test_every_tool_query_is_scoped_even_when_asked_for_the_other_participant(merged, embedder):
    """Each named query the tools and consolidation run, asked about P37's ids as P09 (and the
    other way round), returns only the asking participant's records."""
    from memora_graph.queries import load_queries

    views = {p: MemoryView(merged, p, embedder) for p in SMALL}
    probe = {p: {"ids": sorted(views[p].vectors("segment").ids)[:20] + sorted(views[p].entities)[:10],
                 "entity": sorted(views[p].entities)[0], "video": sorted(views[p].videos)[0],
                 "videos": sorted(views[p].videos)[:2],
                 "vector": views[p].vectors("segment").mat[0].tolist(), "query": "take put wash knife plate",
                 "id": sorted(views[p].vectors("segment").ids)[0]}
             for p in SMALL}
    names = [n for n in load_queries() if n.startswith(("_tool_", "_consolidate_", "_inferred_")) and
             not n.startswith("_tool_hnsw") and not load_queries()[n].writes]
    assert len(names) > 20
    for a, b in ((SMALL[0], SMALL[1]), (SMALL[1], SMALL[0])):
        for name in names:
            params = {k: v for k, v in probe[b].items() if k in load_queries()[name].params}
            rows = merged.fetch(name, participant=a, **params)
            leaked = {i for i in _ids(rows) if i.startswith(b)}
            assert not leaked, f"{name} as {a} returned {b}'s {sorted(leaked)[:3]}"


def test_state_at_time_follows_the_hand_built_history(hand_store, embedder):
    view = MemoryView(hand_store, "P01", embedder)

    def at(t):
        r = call_tool(view, "get_state_at_time", {"time_seconds": t})  # one video: no `video` needed
        return {o.name: o for o in r.visible_objects}, r

    objs, r = at(30)
    assert set(objs) == {"spoon", "mug", "kettle"}, "the sponge is first seen at 80 s"
    assert (objs["mug"].state, objs["mug"].location, objs["mug"].relative_to, objs["mug"].relation) == \
        ("placed", "sink_area", "sink", "INSIDE")
    assert objs["kettle"].state == "on" and objs["spoon"].state == "placed"
    assert r.segment_id == "P01_101#t0003" and r.current_activity == "put mug in sink."
    assert set(r.evidence) >= {"P01_101#t0003", objs["mug"].event_id}

    objs, _ = at(70)
    assert objs["mug"].state == "washed", "an entry at exactly t counts"
    assert objs["kettle"].state == "off"

    objs, _ = at(90)
    assert "spoon" not in objs, "last seen at 3 s: gone after the 60 s window"
    assert objs["kettle"].state == "off" and objs["sponge"].held_by == "hand"
    assert objs["mug"].since_seconds == 70.0

    objs, _ = at(1)
    assert objs == {}
    narrow = call_tool(view, "get_state_at_time", {"time_seconds": 90, "window": 10})
    assert {o.name for o in narrow.visible_objects} == {"sponge"}
    with pytest.raises(ToolError, match="invalid arguments"):
        call_tool(view, "get_state_at_time", {"time_seconds": "soon"})


def test_object_history_and_transitions(hand_store, embedder):
    view = MemoryView(hand_store, "P01", embedder)
    r = call_tool(view, "get_object_history", {"object_query": "mug"})
    assert r.match_type == "exact" and r.entity_id == "P01:mug"
    assert [h.state for h in r.state_history] == ["held", "placed", "washed"]
    assert [(x["from"], x["to"]) for x in r.as_json()["location_transitions"]] == [("counter_area", "sink_area")]
    assert r.all_locations_observed == ["counter_area", "sink_area"]
    miss = call_tool(view, "get_object_history", {"object_query": "helicopter"})
    assert miss.found is False and "helicopter" in miss.error and "state_history" not in miss.as_json()


def test_near_duplicates_collapse_into_the_better_record(hand_store, embedder):
    view = MemoryView(hand_store, "P01", embedder)
    r = call_tool(view, "search_activities", {"query": "put the mug in the sink", "top_k": 10})
    summaries = [x.summary for x in r.results]
    assert summaries[0].startswith("put mug in sink")
    assert len({s.rstrip(".") for s in summaries}) == len(summaries), "no two near-identical records"
    top = r.results[0]
    assert {top.segment_id, *top.duplicates} == {"P01_101#t0002", "P01_101#t0003"}
    blanks = [x for x in r.results if x.summary == "no narrated action"]
    assert len(blanks) <= 1 and (not blanks or len(blanks[0].duplicates) == 2)
    # the rule itself: >= 0.95 collapses, below does not
    ids = ["a", "b", "c"]
    vecs = np.array([[1.0, 0.0], [0.96, np.sqrt(1 - 0.96 ** 2)], [0.90, np.sqrt(1 - 0.90 ** 2)]])
    kept = dedup([Candidate(i) for i in ids], VectorTable(ids, vecs), 0.95, 10)
    assert [c.id for c in kept] == ["a", "c"] and kept[0].duplicates == ["b"]


def test_results_are_deterministic_and_json(small_bank, embedder):
    path, _ = small_bank
    outs = []
    for _ in range(2):
        with MemoryView.open(path, "P37", embedder) as view:
            view.encoder.clear()
            outs.append([call_tool(view, n, a).as_json() for n, a in [
                ("search", {"query": "wash the pan"}), ("search_objects", {"query": "knife", "top_k": 10}),
                ("search_activities", {"query": "cut vegetables"}), ("search_patterns", {"query": "after washing"}),
                ("get_routine_skill", {"goal_query": "wash pan"}), ("get_preferences", {"query": "knife"}),
                ("get_object_history", {"object_query": "pan"})]])
    assert json.dumps(outs[0], sort_keys=True) == json.dumps(outs[1], sort_keys=True)
    obj = outs[0][1]["results"]
    assert len(obj) <= 10 and all(set(o["score"]) >= {"vector", "keyword", "graph", "fused"} for o in obj)
    assert all(o["evidence"] and o["evidence"][0] == o["entity_id"] for o in obj)
    routines = outs[0][4]["routines"]
    tasks = [r for r in routines if r["kind"] == "task_routine"]  # added after the top k (TASK_EXTRA)
    assert len(routines) - len(tasks) <= 3 and len(tasks) <= 5 and all(r["supporting_episodes"] for r in routines)
    assert [r["kind"] for r in routines] == sorted((r["kind"] for r in routines), key=lambda k: k == "task_routine")


def test_registry_schemas_and_argument_checks(hand_store, embedder):
    names = [s["function"]["name"] for s in tool_schemas()]
    assert names == ["search", "search_objects", "search_activities", "get_video_activities", "get_routine_skill",
                     "get_preferences", "search_patterns", "get_object_history", "get_state_at_time"]
    assert "search_environment" in tool_names()
    fn = tool_schemas(["get_routine_skill"])[0]
    assert fn["type"] == "function" and fn["function"]["parameters"]["required"] == ["goal_query"]
    assert fn["function"]["parameters"]["properties"]["top_k"]["default"] == 3
    view = MemoryView(hand_store, "P01", embedder)
    by_name = call_tool(view, "search_objects", {"name": "kettle", "top_k": 1})  # the paper's prompt writes name=
    assert [o.name for o in by_name.results] == ["kettle"]
    with pytest.raises(ToolError, match="top_k"):
        call_tool(view, "search_objects", {"query": "kettle", "top_k": 0})
    with pytest.raises(ToolError, match="no tool 'fly'"):
        call_tool(view, "fly", {})
    episodic = call_tool(view, "get_routine_skill", {"goal_query": "boil water"})
    assert episodic.routines == [] and "MEMORA-Episodic" in episodic.error


def test_tool_cli(small_bank):
    path, _ = small_bank
    runner = CliRunner()
    r = runner.invoke(main, ["tools", "--json"])
    assert r.exit_code == 0 and "get_routine_skill" in {s["function"]["name"] for s in json.loads(r.output)}
    r = runner.invoke(main, ["tools"])
    assert r.exit_code == 0 and "goal_query" in r.output
    r = runner.invoke(main, ["tool", str(path), "get_routine_skill", "wash the pan", "--participant", "P37", "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["participant"] == "P37" and out["arguments"]["goal_query"] == "wash the pan"
    r = runner.invoke(main, ["tool", str(path), "search_objects", "--participant", "P37", "--arg", "query", "knife",
                             "--arg", "top_k", "2", "--nl"])
    assert r.exit_code == 0 and len(r.output.strip().splitlines()) == 2
    r = runner.invoke(main, ["tool", str(path), "search", "knife", "--participant", "P37", "--csv"])
    assert r.exit_code == 0 and "similarity" in r.output.splitlines()[0]
    r = runner.invoke(main, ["tool", str(path), "nope", "--participant", "P37"])
    assert r.exit_code == 1 and "no tool 'nope'" in r.output
    r = runner.invoke(main, ["tool", str(path), "search", "knife", "--participant", "P01"])
    assert r.exit_code == 1 and "not in this bank" in r.output


@pytest.mark.parametrize("argv", [
    ["search", "knife"],
    ["get_object_history", "knife"],
    ["get_routine_skill", "wash the pan"],
    ["search_objects", "--arg", "query", "knife", "--arg", "top_k", "1"],
], ids=lambda a: a[0])
def test_tool_without_json_prints_a_readable_summary(small_bank, argv):
    """`memora tool` without --json reads as lines of words, not a wide wrapped table: what was
    asked, then one numbered line per record (its id and what it says) in the result's rank order,
    every line short enough for a terminal; a count says "1 record", not "1 records"."""
    path, _ = small_bank
    runner = CliRunner()
    base = ["tool", str(path), *argv, "--participant", "P37"]
    whole = json.loads(runner.invoke(main, [*base, "--json"]).output)
    r = runner.invoke(main, base)
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert lines[0].startswith(f"{argv[0]} on P37's memory (")
    assert not any(ch in r.output for ch in "┃│┏━"), "a table, not a summary"
    assert max(map(len, lines)) <= 160
    for name in ("results", "objects", "activities", "places", "patterns", "routines", "preferences", "state_history"):
        recs = whole.get(name) or []
        if not recs:
            continue
        assert f"{name} ({len(recs)} record{'' if len(recs) == 1 else 's'}):" in lines
        start = lines.index(f"{name} ({len(recs)} record{'' if len(recs) == 1 else 's'}):")
        for i, rec in enumerate(recs, 1):
            rid = next(rec[f] for f in ("entity_id", "segment_id", "place_id", "pattern_id", "routine_id",
                                        "preference_id", "event_id", "id") if rec.get(f))
            assert lines[start + i].split()[:2] == [f"{i}.", rid]
    assert any(whole.get(n) for n in ("results", "objects", "routines", "state_history")), "the call found records"


def test_perf_tools_reports_every_tool_and_recall(small_bank):
    from memora_graph.cli.perf.tools import TOOLS, run_perf

    path, _ = small_bank
    report = run_perf(path, ["P37"], n_queries=2, recipes=["inprocess", "fts"], hnsw=True, echo=lambda *_: None)
    lat = report.latency
    for recipe in ("inprocess", "fts"):
        assert set(lat.filter(pl.col("recipe") == recipe)["tool"]) == set(TOOLS)
    assert (lat["calls"] > 0).all() and "floor" in lat["recipe"].to_list()
    rec = {(r["search"], r["table"]): r["recall@10"] for r in report.recall.to_dicts()}
    assert rec[("numpy exact", "segment")] == 1.0 and rec[("kuzu brute force", "segment")] >= 0.9
    assert ("kuzu hnsw", "segment") in rec


def test_per_view_indexes_answer_as_a_scan_of_every_entity(small_bank, embedder):
    """The objects at a place (search_environment), the share of the query's objects a routine or
    preference links (its graph score) and the entities an object reference matches
    (get_object_history) come from indexes made once per view: each equals a scan of every entity."""
    from memora_graph.retrieve.tools import grounded_entities, resolve_object

    with MemoryView.open(small_bank[0], "P37", embedder) as view:
        ents = view.entities
        for q in ("sink", "hob", "counter top", "fridge", "cupboard drawer"):
            for rec in call_tool(view, "search_environment", {"query": q, "top_k": 30}).results:
                here = sorted((e for e in ents.values() if e["status"] == "active" and e["location"] == rec.place_id),
                              key=lambda e: (-(e["n_observations"] or 0), e["id"]))
                assert rec.objects_here == [e["name"] for e in here[:10]]
        links: dict[str, set[str]] = {}
        for r in view.fetch("_tool_inferred_links"):
            links.setdefault(r["id"], set()).add(r["entity"])
        graded = 0
        for q in ("wash the pan", "knife", "cut the onion", "put the plate in the rack", "spoon and bowl"):
            kinds = {ents[e]["kind"] for e in grounded_entities(view, q)}
            prefs = call_tool(view, "get_preferences", {"query": q, "top_k": 30}).preferences
            routines = call_tool(view, "get_routine_skill", {"goal_query": q, "top_k": 30}).routines
            records = [(p.preference_id, p.score) for p in prefs] + [(r.routine_id, r.score) for r in routines]
            for rid, score in records:
                used = {ents[e]["kind"] for e in links.get(rid, ()) if e in ents}
                assert score.graph == (round(len(used & kinds) / len(kinds), 4) if kinds else None), (q, rid)
                graded += bool(score.graph)
        assert graded, "some records share the query's objects"
        names = sorted({e["name"] for e in ents.values()})
        for text in ["pan", "Knife", " tap ", "chopping board", "bo", "nothing like it", *names[:25], *sorted(ents)[:5]]:
            t = text.strip().lower()
            slug = t.replace(" ", "_")
            exact = [i for i, e in ents.items() if t in (i.lower(), e["object_id"], e["kind"], e["name"].lower())
                     or slug in (e["object_id"], e["kind"])]
            sub = [i for i, e in ents.items() if slug in e["object_id"] or t in e["name"].lower()]
            ids, how = resolve_object(view, text)
            if exact or sub:
                order = sorted(exact or sub,
                               key=lambda i: (ents[i]["status"] != "active", -(ents[i]["n_observations"] or 0), i))
                assert (ids, how) == (order, "exact" if exact else "substring"), text
            else:
                assert how == "embedding", text

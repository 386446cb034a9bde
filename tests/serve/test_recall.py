"""`recall`: the typed query served over MCP, driven by the official `mcp` client over stdio
against a real small bank (P09, P37), one test per operation. Gold comes from the annotations
(`bench.behaviour`), never from the reader: an agent fills the schema, no words are parsed."""

from __future__ import annotations

from collections import Counter

import anyio
import pytest
from mcp import Client

from memora_graph.bench.behaviour import PUT_VERB_KEYS, build_behaviours
from memora_graph.perceive.annotations import load_annotations

from tests.serve.test_serve import stdio

PID = "P37"


@pytest.fixture(scope="module")
def behaviour():
    return build_behaviours(load_annotations(participants=[PID]))[PID]


def recall(bank, arguments: dict) -> dict:
    """One `recall` call over stdio (the server bound to P37); the structured answer."""
    async def run() -> dict:
        async with Client(stdio(bank, "--participant", PID)) as client:
            tools = {t.name: t for t in (await client.list_tools()).tools}
            assert "recall" in tools and "operation" in tools["recall"].input_schema["properties"]
            res = await client.call_tool("recall", arguments)
            assert not res.is_error, res.content
            return res.structured_content
    return anyio.run(run)


def _frequent(b, videos: int = 2):
    """The most frequent action seen in at least `videos` videos (with its count per video)."""
    per: dict = {}
    for v in b.videos:
        for s in b.steps_by_video[v]:
            if s.action.noun and s.action.noun != "hand":
                per.setdefault(s.action, Counter())[v] += 1
    ok = sorted((a for a, c in per.items() if len(c) >= videos), key=lambda a: (-sum(per[a].values()), a))
    return ok[0], per[ok[0]]


def _act(a) -> dict:
    return {"verb": a.verb, "objects": [a.noun]}


def test_recall_count_in_one_video(small_bank, behaviour):
    a, per = _frequent(behaviour)
    video = max(per, key=per.get)
    got = recall(small_bank[0], {"operation": "count", "subject": _act(a), "scope": {"videos": [video]}})
    assert got["kind"] == "count" and abs(got["count"] - per[video]) <= max(1, round(0.2 * per[video]))
    assert got["count"] < sum(per.values()) or len(per) == 1  # the scope counts one video, not all of them
    assert got["evidence"] and 0.0 <= got["confidence"] <= 1.0


def test_recall_exists_yes_and_no_by_scope(small_bank, behaviour):
    per_action: dict = {}
    for v in behaviour.videos:
        for s in behaviour.steps_by_video[v]:
            per_action.setdefault(s.action, set()).add(v)
    a = next(a for a, vs in sorted(per_action.items()) if a.noun and len(vs) == 1 and a.verb not in PUT_VERB_KEYS
             and sum(1 for b, ws in per_action.items() if b.verb == a.verb and b.noun == a.noun) == 1)
    (inside,) = per_action[a]
    outside = next(v for v in behaviour.videos if v != inside)
    yes = recall(small_bank[0], {"operation": "exists", "subject": _act(a), "scope": {"videos": [inside]}})
    no = recall(small_bank[0], {"operation": "exists", "subject": _act(a), "scope": {"videos": [outside]}})
    assert yes["yes"] is True and no["yes"] is False, (a, yes["answer"], no["answer"])


def test_recall_where_last_put_in_a_video(small_bank, behaviour):
    puts = [s for v in behaviour.videos for s in behaviour.steps_by_video[v]
            if s.place and s.action.verb in PUT_VERB_KEYS and s.place != s.action.noun and s.action.noun != "hand"]
    last = puts[-1]
    got = recall(small_bank[0], {"operation": "where", "subject": {"objects": [last.action.noun]},
                                 "scope": {"videos": [last.video_id]}, "selector": "last"})
    assert got["kind"] == "place" and got["place"]["place"] == last.place, got["answer"]


def test_recall_when_first(small_bank, behaviour):
    a, per = _frequent(behaviour)
    first = next(s for v in behaviour.videos for s in behaviour.steps_by_video[v] if s.action == a)
    got = recall(small_bank[0], {"operation": "when", "subject": _act(a), "selector": "first"})
    assert got["moment"]["video"] == first.video_id and abs(got["moment"]["time_seconds"] - first.start_s) < 15


def test_recall_which_video_last(small_bank, behaviour):
    a, per = _frequent(behaviour)
    last = [s for v in behaviour.videos for s in behaviour.steps_by_video[v] if s.action == a][-1]
    got = recall(small_bank[0], {"operation": "which_video", "subject": _act(a), "selector": "last"})
    assert got["moment"]["video"] == last.video_id


def test_recall_list_last_thing_in_a_video(small_bank, behaviour):
    video = behaviour.videos[0]
    last = behaviour.steps_by_video[video][-1]
    got = recall(small_bank[0], {"operation": "list", "scope": {"videos": [video]}, "selector": "last"})
    assert got["log"] and got["log"][0]["video"] == video
    assert abs(got["log"][0]["time_seconds"] - last.start_s) < 10, (got["answer"], last.narration)


def test_recall_list_all_is_cut_and_says_so(small_bank, behaviour):
    video = max(behaviour.videos, key=lambda v: len(behaviour.steps_by_video[v]))
    got = recall(small_bank[0], {"operation": "list", "scope": {"videos": [video]}, "selector": "all"})
    assert len(got["log"]) < len(behaviour.steps_by_video[video])
    assert got["cut"] and "scope.start" in got["cut"]


def test_recall_next(small_bank, behaviour):
    a, _ = _frequent(behaviour)
    follows = Counter()
    for v in behaviour.videos:
        runs = behaviour.runs_by_video[v]
        for r0, r1 in zip(runs, runs[1:]):
            if r0.action == a:
                follows[(r1.action.verb, r1.action.noun)] += 1
    got = recall(small_bank[0], {"operation": "next", "relation": "after", "anchor": _act(a)})
    assert got["actions"] and (got["actions"][0]["verb"], got["actions"][0]["noun"]) in follows


def test_recall_previous(small_bank, behaviour):
    a, _ = _frequent(behaviour)
    precedes = Counter()
    for v in behaviour.videos:
        runs = behaviour.runs_by_video[v]
        for r0, r1 in zip(runs, runs[1:]):
            if r1.action == a:
                precedes[(r0.action.verb, r0.action.noun)] += 1
    got = recall(small_bank[0], {"operation": "previous", "subject": _act(a)})  # the subject is the anchor
    assert got["actions"] and (got["actions"][0]["verb"], got["actions"][0]["noun"]) in precedes
    assert (a.verb, a.noun) not in {(x["verb"], x["noun"]) for x in got["actions"]}  # not the action itself


def test_recall_steps(small_bank, behaviour):
    got = recall(small_bank[0], {"operation": "steps", "subject": {"verb": "wash", "objects": ["chicken"],
                                                                   "goal": "wash chicken"}})
    assert got["kind"] == "routine" and len(got["steps"]) >= 2 and got["evidence"]


def test_recall_state_at_a_moment(small_bank, behaviour):
    video = behaviour.videos[0]
    got = recall(small_bank[0], {"operation": "state", "scope": {"videos": [video], "at": 60}})
    assert got["kind"] == "state" and got["states"]
    assert all(s["video"] == video and s["time_seconds"] <= 60 for s in got["states"])


def test_recall_duration_of_a_video(small_bank, behaviour):
    video = behaviour.videos[0]
    steps = behaviour.steps_by_video[video]
    got = recall(small_bank[0], {"operation": "duration", "scope": {"videos": [video]}})
    span = steps[-1].start_s - steps[0].start_s
    assert got["kind"] == "duration" and abs(got["seconds"] - span) <= 0.1 * span + 10


def test_recall_refuses_nonsense_and_bad_fields(small_bank):
    got = recall(small_bank[0], {"operation": "count", "subject": {"verb": "open", "objects": ["fridge"]},
                                 "selector": "first"})
    assert got["reason"] == "invalid_query" and "count" in got["detail"]

    async def run():
        from mcp import MCPError

        async with Client(stdio(small_bank[0], "--participant", PID)) as client:
            with pytest.raises(MCPError) as info:
                await client.call_tool("recall", {"operation": "fly", "colour": 1})
            assert {f["field"] for f in info.value.data["fields"]} >= {"operation", "colour"}
    anyio.run(run)

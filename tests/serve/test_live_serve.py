"""`memora serve --writable`: the MCP `remember` tool, reads that see it at once, a bearer token over
HTTP, background incremental consolidation; and `memora consolidate --incremental` equal to a
batch run. Real Kùzu in tmp dirs, the bundled MiniLM, the mcp SDK's client over loopback."""

from __future__ import annotations

import json

import urllib.error
import urllib.request

import anyio
import pytest
from click.testing import CliRunner
from mcp import Client, MCPError
from mcp.client.streamable_http import create_mcp_http_client, streamable_http_client

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.consolidate.live import IncrementalConsolidation, consolidate_incremental, consolidation_cache
from memora_graph.consolidate.run import consolidate_participant
from memora_graph.errors import BankError
from memora_graph.form.live import LiveWriter, Moment
from memora_graph.integrity.verify import verify_bank
from memora_graph.serve import MemoryService
from memora_graph.cli.perf.serve import ServerProcess
from memora_graph.store import Store

from support.live import moments

TOKEN = "s3cret-token"


def test_remember_tool_in_process_and_reads_see_it(tmp_path):
    bank = tmp_path / "bank"
    service = MemoryService(bank, "P01", writable=True)
    try:
        assert "remember" in {e.name for e in service.endpoints()}
        before = service.call("search_objects", {"query": "kettle"})
        assert not service.call("get_object_history", {"object_query": "kettle"})["found"]  # (its names index made)
        got = service.call("remember", {"text": "put the kettle on the counter", "video": "kitchen-1", "start": 12.5,
                                        "end": 14.0})
        assert got["segment"] == "kitchen-1#t0000" and got["ops"][0]["op"] == "ADD"
        kettle = got["ops"][0]["entity"]
        after = service.call("search_objects", {"query": "kettle"})
        assert kettle not in json.dumps(before) and kettle in json.dumps(after)  # the next read sees it
        history = service.call("get_object_history", {"object_query": "kettle"})
        assert "kitchen-1" in json.dumps(history)
        acts = service.call("search_activities", {"query": "kettle counter"})
        assert "kitchen-1#t0000" in json.dumps(acts)
        again = service.call("remember", {"text": "put the kettle on the counter", "video": "kitchen-1", "start": 12.5})
        assert again["duplicate"] and again["ops"] == got["ops"]
        # the database is held open here, so no confined child could read it: no cypher tool by default
        assert "cypher" not in {e.name for e in service.endpoints()}
    finally:
        service.close()
    unconfined = MemoryService(bank, "P01", writable=True, unconfined_cypher=True)
    try:  # asked for explicitly, it reads in this process, guarded, and sees what was remembered
        rows = unconfined.call("cypher", {"query": "MATCH (s:Segment) WHERE s.participant = $participant "
                                                   "RETURN count(s) AS n"})
        assert rows["rows"] == [{"n": 1}]
        with pytest.raises(Exception, match="never allowed|refused|not allowed"):
            unconfined.call("cypher", {"query": "UNWIND [1] AS AS LOAD FROM '/etc/passwd' (file_format='csv', "
                                                "header=false, delim=':') RETURN *"})
    finally:
        unconfined.close()
    assert verify_bank(bank).ok
    with pytest.raises(BankError, match="one participant"):
        MemoryService(bank, None, writable=True)


def _client(url: str, token: str | None):
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    return Client(streamable_http_client(url, http_client=create_mcp_http_client(headers=headers)))


def test_remember_over_http_needs_the_token(tmp_path):
    bank = tmp_path / "bank"
    refused = CliRunner().invoke(main, ["serve", str(bank), "--participant", "P01", "--writable", "--transport", "http"])
    assert refused.exit_code == 2 and "--token" in refused.output
    server = ServerProcess(bank, "P01", "--writable", "--token", TOKEN)
    try:
        assert server.url.startswith("http://127.0.0.1:")  # loopback by default
        with pytest.raises(urllib.error.HTTPError) as refused_http:
            urllib.request.urlopen(urllib.request.Request(server.url, data=b"{}", method="POST"), timeout=60)
        assert refused_http.value.code == 401

        async def main_() -> None:
            async with _client(server.url, TOKEN) as client:
                tools = {t.name: t for t in (await client.list_tools()).tools}
                assert "remember" in tools and tools["remember"].annotations.read_only_hint is False
                res = await client.call_tool("remember", {"text": "#C C takes a knife from the drawer",
                                                          "video": "ego-1", "start": 3.0, "end": 4.0})
                assert not res.is_error, res.content
                ops = res.structured_content["ops"]
                assert {o["op"] for o in ops} == {"ADD"} and any(o["entity"] == "P01:knife" for o in ops)
                found = await client.call_tool("get_object_history", {"object_query": "knife"})
                assert "ego-1" in json.dumps(found.structured_content)
                with pytest.raises(MCPError, match="start"):  # invalid params, naming the field
                    await client.call_tool("remember", {"text": "open the fridge", "video": "ego-1", "start": -2})

        anyio.run(main_)
    finally:
        server.stop()
    assert verify_bank(bank).ok


def _inferred(store: Store, p: str) -> dict:
    routines = store.query("MATCH (r:Routine) WHERE r.participant = $p RETURN r.id AS id, r.goal AS goal, "
                           "r.canonical_steps AS steps, r.count AS count, r.supporting_episodes AS ev ORDER BY id",
                           {"p": p}).to_dicts()
    prefs = store.query("MATCH (r:Preference) WHERE r.participant = $p RETURN r.id AS id, r.statement AS s, "
                        "r.count AS count, r.supporting_episodes AS ev ORDER BY id", {"p": p}).to_dicts()
    return {"routines": routines, "preferences": prefs}


def test_incremental_consolidation_equals_a_batch_run(tmp_path):
    """A stream of remembers with incremental consolidation after each batch gives the same
    routines and preferences as one full consolidation of the same memory."""
    from memora_graph.embed import get_embedder

    bank = tmp_path / "bank"
    state = IncrementalConsolidation(consolidation_cache(bank, "P01"))  # where the CLI keeps it
    stream = [moments(40, video=f"day-{d}", offset=0.0) for d in range(3)]
    with LiveWriter(bank, "P01") as memory:
        for day in stream:
            for m in day:
                memory.remember(m)
            consolidate_incremental(memory.store, memory.store, "P01", memory.embedder, state)
        assert state.reused == 2 and state.recomputed == 1  # the last run: only the new video's pass
        live = _inferred(memory.store, "P01")
        consolidate_participant(memory.store, "P01", get_embedder())
        batch = _inferred(memory.store, "P01")
    assert live == batch and live["preferences"], live
    # the CLI: incremental runs record in the manifest, and verify still passes
    res = CliRunner().invoke(main, ["consolidate", str(bank), "--incremental", "--json"])
    assert res.exit_code == 0, res.output
    row = json.loads(res.output)[0]
    assert row["videos_recomputed"] == 0 and row["videos_reused"] == 3  # nothing new since
    assert Bank(bank).manifest()["participants"]["P01"]["consolidated"]
    assert verify_bank(bank).ok


def test_background_consolidation_in_the_writable_server(tmp_path):
    bank = tmp_path / "bank"
    service = MemoryService(bank, "P01", writable=True, consolidate_every=25)
    try:
        assert service.call("get_preferences", {"query": "put the milk in the fridge"})["preferences"] == []
        for d in range(2):
            for m in moments(30, video=f"day-{d}"):
                service.call("remember", {"text": m.text, "video": m.video, "start": m.start, "end": m.end})
        assert service.consolidator.wait(300)
        assert service.consolidator.error is None and service.consolidator.runs
        prefs = service.call("get_preferences", {"query": "put the milk in the fridge"})["preferences"]
        assert prefs and "fridge" in json.dumps(prefs).lower()  # the new records, read after the swap
    finally:
        service.close()
    assert verify_bank(bank).ok

"""`memora serve`: the bank as an MCP server, driven by the `mcp` SDK's own client over stdio and
over streamable HTTP on loopback, against a real small bank (P09, P37)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

import anyio
import pytest
from click.testing import CliRunner
from mcp import Client, MCPError, StdioServerParameters

from memora_graph.cli import main
from memora_graph.errors import BankError
from memora_graph.queries import load_queries
from memora_graph.retrieve import specs
from memora_graph.serve import ArgumentError, MemoryService
from memora_graph.cli.perf.serve import ServerProcess
from support.bankfiles import without_derived

ROOT = Path(__file__).resolve().parents[2]
INVALID_PARAMS = -32602

# valid arguments for every served tool, for P37 (videos P37_101..103)
CALLS = {
    "search": {"query": "wash the chicken"},
    "search_objects": {"query": "knife", "top_k": 3},
    "search_activities": {"query": "cut the carrot"},
    "get_video_activities": {"video": "P37_101", "top_k": 5},
    "search_environment": {"query": "sink"},
    "get_routine_skill": {"goal_query": "wash chicken"},
    "get_preferences": {"query": "chicken"},
    "search_patterns": {"query": "chicken"},
    "get_object_history": {"object_query": "carrot", "max_entries": 5},
    "get_state_at_time": {"time_seconds": 60, "video": "P37_101"},
    "ask": {"question": "After P37 takes the chicken, what do they usually do next?"},
    "recall": {"operation": "count", "subject": {"verb": "take", "objects": ["chicken"]}},
    "plan": {"goal": "wash the chicken"},
    "cypher": {"query": "MATCH (e:Entity) WHERE e.participant = $participant RETURN e.object_id AS id ORDER BY id "
                        "LIMIT 3"},
}
NAMED_VALUES = {"object": "carrot", "video": "P37_101", "id": "P37:routine:none"}


def expected_tools() -> list[str]:
    named = [f"query_{q.name}" for q in load_queries().values()
             if not q.name.startswith("_") and not q.writes and "participant" in q.params]
    return [s.name for s in specs("memora")] + ["ask", "recall", "plan", "cypher"] + named


def stdio(bank: Path, *extra: str) -> StdioServerParameters:
    env = {"PYTHONPATH": str(ROOT)}
    env.update({k: v for k, v in os.environ.items() if k.startswith(("MEMORA_", "XDG_"))})
    return StdioServerParameters(command=sys.executable, args=["-m", "memora_graph.cli", "serve", str(bank), *extra],
                                 env=env)


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


async def refused(client: Client, name: str, arguments: dict) -> MCPError:
    with pytest.raises(MCPError) as info:
        await client.call_tool(name, arguments)
    assert info.value.code == INVALID_PARAMS, info.value
    return info.value


def test_stdio_lists_and_calls_every_tool(small_bank):
    """Unbound (each call names its participant), with output schemas: the SDK client checks
    every result against the schema the server advertised."""
    bank, _ = small_bank
    before = {p.name: sha(p) for p in bank.glob("*.kuzu")}
    manifest = _without_derived(bank)

    async def run() -> None:
        async with Client(stdio(bank, "--output-schemas")) as client:
            listed = (await client.list_tools()).tools
            assert [t.name for t in listed] == expected_tools()
            by_name = {t.name: t for t in listed}
            for spec in specs("memora"):  # the argument schemas are the registry's, plus `participant`
                schema = by_name[spec.name].input_schema
                registry = spec.schema()["function"]["parameters"]
                assert {k: v for k, v in schema["properties"].items() if k != "participant"} == registry["properties"]
                assert schema["required"] == ["participant", *registry["required"]]
                assert schema["properties"]["participant"]["enum"] == ["P09", "P37"]
                assert by_name[spec.name].output_schema and by_name[spec.name].annotations.read_only_hint

            for tool in listed:
                args = CALLS.get(tool.name) or {p: NAMED_VALUES[p] for p in tool.input_schema["properties"]
                                                if p != "participant"}
                res = await client.call_tool(tool.name, {"participant": "P37", **args})
                assert not res.is_error, (tool.name, res.content)
                data = res.structured_content
                assert data["participant"] == "P37", tool.name
                assert json.loads(res.content[0].text) == data
            # what the results hold
            res = await client.call_tool("get_object_history", {"participant": "P37", "object_query": "carrot"})
            assert res.structured_content["found"] and res.structured_content["entity_id"] == "P37:carrot"
            res = await client.call_tool("query_object_history", {"participant": "P37", "object": "carrot",
                                                                     "video": "P37_102"})
            rows = res.structured_content["rows"]
            assert rows and {r["entity"] for r in rows} == {"P37:carrot"}
            res = await client.call_tool("cypher", {"participant": "P37", **CALLS["cypher"]})
            assert res.structured_content["columns"] == ["id"] and len(res.structured_content["rows"]) == 3
            res = await client.call_tool("ask", {"participant": "P37", **CALLS["ask"], "choices": [
                "breaks the chicken apart", "puts the chicken in the fridge"]})
            assert res.structured_content["letter"] == "A" and res.structured_content["evidence"]
            res = await client.call_tool("plan", {"participant": "P37", **CALLS["plan"]})
            steps = res.structured_content["steps"]
            assert steps and any("chicken" in s["object"] for s in steps) and any(s["evidence"] for s in steps)
            assert all({"verb", "object", "place", "preconditions", "evidence"} <= set(s) for s in steps)

            # bad arguments: a JSON-RPC error naming each field at fault
            e = await refused(client, "search_objects", {"participant": "P37", "query": "knife", "top_k": 99})
            assert "top_k" in e.message and e.data["fields"][0]["field"] == "top_k"
            e = await refused(client, "get_state_at_time", {"participant": "P37", "time_seconds": "noon", "colour": 1})
            assert {f["field"] for f in e.data["fields"]} == {"time_seconds", "colour"}
            e = await refused(client, "search", {"query": "knife"})
            assert "participant" in e.message and "required" in e.message
            e = await refused(client, "search", {"participant": "P99", "query": "knife"})
            assert "participant" in e.message and "P99 is not in this bank" in e.message
            e = await refused(client, "ask", {"participant": "P37", "question": "What next?", "choices": ["a"] * 5})
            assert "choices" in e.message
            e = await refused(client, "query_segments", {"participant": "P37"})
            assert "video" in e.message
            e = await refused(client, "delete_everything", {})
            assert "no tool 'delete_everything'" in e.message

            # a call the tool cannot answer is a tool error in words, not a protocol error
            res = await client.call_tool("get_state_at_time", {"participant": "P37", "time_seconds": 5,
                                                               "video": "P09_103"})
            assert res.is_error and "P09_103" in res.content[0].text

            # writes are impossible: the Cypher guard refuses them before anything runs
            for text in ("MATCH (e:Entity) SET e.name = 'x'", "CREATE (e:Entity {id: 'P37:x'})",
                         "MATCH (e:Entity) DETACH DELETE e", "COPY Entity TO '/tmp/entities.csv'",
                         f"ATTACH '{bank / 'P09.kuzu'}' AS other (dbtype kuzu)",
                         "MATCH (e:Entity) RETURN e.id; MATCH (e:Entity) DELETE e"):
                res = await client.call_tool("cypher", {"participant": "P37", "query": text})
                assert res.is_error and res.content[0].text.startswith("refused"), (text, res.content)
                # in an agent's terms: it has no `memora query` command and no --write flag
                assert "memora query" not in res.content[0].text and "--write" not in res.content[0].text, text
            res = await client.call_tool("cypher", {"participant": "P37", "query": "MATCH (e:Entity) SET e.name = 'x'"})
            assert "this tool only reads; nothing served can change the memory" in res.content[0].text
            # the server still serves after all that
            res = await client.call_tool("search_objects", {"participant": "P09", "query": "kettle"})
            assert not res.is_error and all(r["entity_id"].startswith("P09:") for r in res.structured_content["results"])

    anyio.run(run)
    assert {p.name: sha(p) for p in bank.glob("*.kuzu")} == before
    # only the records of derived files (tool stores written on first use) may have been added
    assert _without_derived(bank) == manifest


def _without_derived(bank) -> dict:
    """The manifest less the records of derived files (bank/derived.py): what serving must not change."""
    return without_derived(json.loads((bank / "manifest.json").read_text()))


def test_http_bound_to_one_participant_shows_nothing_of_another(small_bank):
    """`--participant P09` over streamable HTTP on 127.0.0.1: no `participant` argument, and
    P37's ids, videos and objects give nothing of P37's."""
    bank, _ = small_bank
    server = ServerProcess(bank, "P09")
    try:
        assert server.url.startswith("http://127.0.0.1:") and server.url.endswith("/mcp")

        async def run() -> None:
            async with Client(server.url) as client:
                listed = (await client.list_tools()).tools
                assert [t.name for t in listed] == expected_tools()
                assert all("participant" not in t.input_schema["properties"] for t in listed)
                assert all(t.output_schema is None for t in listed)  # off unless --output-schemas

                res = await client.call_tool("search_objects", {"query": "carrot"})  # P37 has carrots; P09 none
                ids = [r["entity_id"] for r in res.structured_content["results"]]
                assert res.structured_content["participant"] == "P09" and ids
                assert all(i.startswith("P09:") for i in ids)
                res = await client.call_tool("get_object_history", {"object_query": "P37:carrot"})
                assert res.structured_content["found"] is False
                res = await client.call_tool("get_video_activities", {"video": "P37_101"})
                assert res.is_error and "P37_101" in res.content[0].text
                res = await client.call_tool("query_object_history", {"object": "P37:carrot", "video": "P37_102"})
                assert res.structured_content["rows"] == []
                res = await client.call_tool("query_segments", {"video": "P37_101"})
                assert res.structured_content["rows"] == []
                res = await client.call_tool("cypher", {"query": "MATCH (e:Entity) WHERE e.participant = 'P37' "
                                                                 "RETURN e.id"})
                assert not res.is_error and res.structured_content["rows"] == []
                res = await client.call_tool("cypher", {"query": "MATCH (e:Entity) RETURN DISTINCT e.participant AS p"})
                assert res.structured_content["rows"] == [{"p": "P09"}]
                res = await client.call_tool("cypher", {"query": "MATCH (e:Entity) WHERE e.participant = $participant "
                                                                 "RETURN e.id", "params": {"participant": "P37"}})
                assert res.is_error and "disagree" in res.content[0].text
                res = await client.call_tool("search", {"query": "chicken", "participant": "P09"})  # its own: fine
                assert not res.is_error
                e = await refused(client, "search", {"query": "chicken", "participant": "P37"})
                assert e.data["fields"] == [{"field": "participant",
                                             "message": "this server serves only P09's memory, not 'P37'"}]
                e = await refused(client, "get_routine_skill", {"goal_query": "x", "top_k": 0})
                assert "top_k" in e.message
                res = await client.call_tool("ask", {"question": "After P09 takes the kettle, what do they do next?"})
                assert res.structured_content["participant"] == "P09"
                assert all(not c["id"].startswith("P37") for c in res.structured_content["evidence"])

        anyio.run(run)
    finally:
        server.stop()


def test_service_binds_and_checks_in_process(small_bank):
    bank, _ = small_bank
    with MemoryService(bank, "P37") as service:
        assert service.call("query_store_counts", {})["rows"][0]["videos"] == 3
        with pytest.raises(ArgumentError) as info:
            service.call("search_activities", {"query": 5, "top_k": "many"})
        assert [f for f, _ in info.value.problems] == ["query", "top_k"]
    with pytest.raises(BankError, match="P05 is not in this bank"):
        MemoryService(bank, "P05")


def test_serve_command_help_and_usage(small_bank, tmp_path):
    bank, _ = small_bank
    runner = CliRunner()
    r = runner.invoke(main, ["serve", "--help"])
    assert r.exit_code == 0 and "Examples:" in r.output and "claude_desktop_config.json" in r.output
    assert "memora serve banks/epic --participant P01" in r.output
    r = runner.invoke(main, ["perf", "serve", "--help"])
    assert r.exit_code == 0 and "memora perf serve banks/epic --participant P01" in r.output
    r = runner.invoke(main, ["serve", str(bank), "--port", "9000"])
    assert r.exit_code == 2 and "--port apply to --transport http" in r.output
    r = runner.invoke(main, ["serve", str(bank), "--participant", "P05"])
    assert r.exit_code == 1 and "P05 is not in this bank (has: P09, P37)" in r.output
    r = runner.invoke(main, ["serve", str(tmp_path)])
    assert r.exit_code == 1 and "no memory bank here" in r.output


def test_serve_respects_the_integrity_check(small_bank, tmp_path):
    """A damaged database is refused before it is served: at start-up when bound to it, as a
    tool error naming the file when a call asks for it."""
    bank, _ = small_bank
    copy = tmp_path / "bank"
    shutil.copytree(bank, copy, ignore=shutil.ignore_patterns(".cache", ".verified.json"))
    db = copy / "P09.kuzu"
    data = bytearray(db.read_bytes())
    data[len(data) // 2: len(data) // 2 + 64] = b"\xff" * 64
    db.write_bytes(bytes(data))
    r = CliRunner().invoke(main, ["serve", str(copy), "--participant", "P09"])
    assert r.exit_code == 1 and "P09.kuzu" in r.output

    async def run() -> None:
        async with Client(stdio(copy)) as client:
            res = await client.call_tool("search", {"participant": "P09", "query": "kettle"})
            assert res.is_error and "P09.kuzu" in res.content[0].text
            res = await client.call_tool("search", {"participant": "P37", "query": "chicken"})
            assert not res.is_error

    anyio.run(run)

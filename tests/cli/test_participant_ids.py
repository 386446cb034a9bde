"""Participant ids a real user chooses (memora_graph/ids.py): "alice" and "robot-7" go through
every command that takes an id (build --narrations, remember, ask, plan, tool, query, serve,
export, import, forget, verify), side by side in one bank, and neither ever sees the other's
files; unsafe names are refused everywhere with the rule in the message."""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import anyio
import pytest
from click.testing import CliRunner
from mcp import Client, StdioServerParameters

from memora_graph.bank import Bank, parse_participants
from memora_graph.cli import main
from memora_graph.cypher_guard import check_participant
from memora_graph.errors import BankError, DataError, QueryRefused
from memora_graph.ids import DB_FILE, is_participant_id
from memora_graph.perceive.narrations import check_moment

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "docs" / "examples" / "narrations.csv"
PEOPLE = ("alice", "robot-7")


def run(*args: str) -> str:
    res = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    assert res.exit_code == 0, f"memora {' '.join(map(str, args))}:\n{res.output}"
    return res.output


def fails(*args: str) -> str:
    res = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    assert res.exit_code != 0, f"memora {' '.join(map(str, args))} did not fail:\n{res.output}"
    assert "Traceback" not in res.output
    return res.output


def test_the_pattern():
    for ok in ("P01", "P99", "alice", "robot-7", "home_2", "A", "7up", "all-7", "x" * 64):
        assert is_participant_id(ok), ok
    for bad in ("", "all", "ALL", "-rf", "_x", "a.b", "../x", "a/b", "x" * 65, "P09\n", "é", "a b", None, 7):
        assert not is_participant_id(bad), bad
    assert DB_FILE.match("robot-7.kuzu").group(1) == "robot-7" and not DB_FILE.match("robot-7.kuzu.wal")
    assert parse_participants("alice,robot-7,P01") == ["alice", "robot-7", "P01"]
    with pytest.raises(BankError, match="letters, digits"):
        parse_participants("alice,../etc")
    with pytest.raises(QueryRefused, match="letters, digits"):
        check_participant("a.b")
    with pytest.raises(DataError, match="field 'participant'"):
        check_moment("row 2", "v1", 0, 1, "open the fridge", participant="bob/../x")
    assert check_moment("row 2", "v1", 0, 1, "open the fridge", participant="robot-7")[0] == "v1"


def _stdio(bank: Path, *extra: str) -> StdioServerParameters:
    env = {"PYTHONPATH": str(ROOT)}
    env.update({k: v for k, v in os.environ.items() if k.startswith(("MEMORA_", "XDG_"))})
    return StdioServerParameters(command=sys.executable, args=["-m", "memora_graph.cli", "serve", str(bank), *extra],
                                 env=env)


def test_alice_and_robot_7_through_every_command(tmp_path):
    bank = tmp_path / "home"
    # build --narrations, one person each (the example's video ids are not EPIC's P01_101 shape)
    for who in PEOPLE:
        run("build", bank, "--narrations", EXAMPLE, "--participant", who)
    assert sorted(Bank(bank).participants()) == sorted(PEOPLE)
    assert (bank / "alice.kuzu").is_file() and (bank / "robot-7.kuzu").is_file()

    # remember: a moment only robot-7 lived
    run("remember", bank, "--participant", "robot-7", "put the colander on the counter", "--video", "garage-1",
        "--start", "3", "--end", "5")
    out = json.loads(run("tool", bank, "search_objects", "colander", "--participant", "robot-7", "--json"))
    assert any("colander" in json.dumps(r) for r in out["results"])
    out = json.loads(run("tool", bank, "search_objects", "colander", "--participant", "alice", "--json"))
    assert not any("colander" in json.dumps(r) for r in out["results"])

    # ask, plan, query
    for who in PEOPLE:
        run("ask", bank, "Where is the milk?", "--participant", who)
        run("plan", bank, "make a cup of tea", "--participant", who)
    rows = run("query", bank, "MATCH (e:Entity) RETURN DISTINCT e.participant AS p", "--participant", "robot-7",
               "--json")
    assert "robot-7" in rows and "alice" not in rows

    # serve: over stdio, each call naming its participant, and bound to one
    async def served() -> None:
        async with Client(_stdio(bank)) as client:
            for who in PEOPLE:
                res = await client.call_tool("search_objects", {"query": "colander", "participant": who})
                assert res.structured_content["participant"] == who
                found = any("colander" in json.dumps(r) for r in res.structured_content["results"])
                assert found == (who == "robot-7")
                res = await client.call_tool("ask", {"question": "Where is the milk?", "participant": who})
                assert not res.is_error
        async with Client(_stdio(bank, "--participant", "robot-7")) as client:
            res = await client.call_tool("search_objects", {"query": "colander"})
            assert res.structured_content["participant"] == "robot-7"
        async with Client(_stdio(bank, "--participant", "alice", "--writable")) as client:  # remember over MCP
            res = await client.call_tool("remember", {"text": "put the colander in the sink", "video": "kitchen 9",
                                                      "start": 4})
            assert not res.is_error and res.structured_content["participant"] == "alice"
            res = await client.call_tool("search_objects", {"query": "colander"})
            assert any("colander" in json.dumps(r) for r in res.structured_content["results"])

    anyio.run(served)

    # export, import into another bank, verify
    exported = tmp_path / "robot-7.json"
    run("export", bank, "--participant", "robot-7", "--out", exported)
    assert json.loads(exported.read_text())["participant"] == "robot-7"
    other = tmp_path / "other"
    run("import", other, exported)
    assert Bank(other).participants() == ["robot-7"]
    out = json.loads(run("tool", other, "search_objects", "colander", "--participant", "robot-7", "--json"))
    assert any("colander" in json.dumps(r) for r in out["results"])
    run("verify", other)
    run("verify", bank)
    run("verify", bank, "--participant", "robot-7")

    # forget "robot-7": alice, and a person whose id is a prefix of it, keep everything
    run("build", bank, "--narrations", EXAMPLE, "--participant", "robot")
    cache = bank / ".cache"
    cache.mkdir(exist_ok=True)
    for name in ("flat1d-robot-0123456789abcdef.json", "flat1d-robot-7-0123456789abcdef.json"):
        (cache / name).write_text("{}")
    (bank / ".trash").mkdir(exist_ok=True)
    (bank / ".trash" / "robot-1700000000000").mkdir()
    run("forget", bank, "--participant", "robot-7", "--yes")
    assert sorted(Bank(bank).participants()) == ["alice", "robot"]
    assert not (bank / "robot-7.kuzu").exists() and (bank / "robot.kuzu").is_file()
    assert (cache / "flat1d-robot-0123456789abcdef.json").exists()
    assert not (cache / "flat1d-robot-7-0123456789abcdef.json").exists()
    assert (bank / ".trash" / "robot-1700000000000").exists()
    shutil.rmtree(bank / ".trash")
    run("verify", bank)


def test_unsafe_ids_are_refused_by_every_command(tmp_path):
    bank = tmp_path / "home"
    for bad in ("../escape", "a.b", "all"):
        out = fails("build", bank, "--narrations", EXAMPLE, "--participant", bad)
        assert "participant" in out
        fails("remember", bank, "--participant", bad, "open the fridge", "--video", "v", "--start", "1")
    assert not any(p.name.startswith("escape") for p in tmp_path.rglob("*"))
    narr = tmp_path / "n.csv"
    narr.write_text("participant,video_id,start,end,text\nalice,v1,0,1,open the fridge\nbad.id,v1,2,3,close it\n")
    out = fails("build", bank, "--narrations", narr)
    assert "row 3" in out and "'participant'" in out

"""`memora export` / `memora import`: a memory leaves one bank and arrives whole in another, or not at all."""

from __future__ import annotations

import json
import shutil

import networkx as nx
import pytest
from click.testing import CliRunner

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.errors import BankError, DataError
from memora_graph.retrieve import MemoryView, call_tool
from memora_graph.stats import bank_stats
from memora_graph.transfer import dump_participant, export_participant, import_participant

TOOL_CALLS = [
    ("search_objects", {"query": "bowl"}),
    ("get_object_history", {"object_query": "pan"}),
    ("search_activities", {"query": "wash the bowl in the sink"}),
    ("get_routine_skill", {"goal_query": "cut carrot"}),
    ("get_preferences", {"query": "where does the chicken go"}),
]


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _snapshot(path):
    """Every file of a bank with its size and modification time: what 'writes nothing' compares."""
    return {p.relative_to(path): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(path.rglob("*"))}


@pytest.fixture(scope="module")
def exported(small_bank, tmp_path_factory):
    path, _ = small_bank
    out = tmp_path_factory.mktemp("export")
    json_file, _ = export_participant(path, "P37", "json", out / "P37.json")
    return path, json_file


def test_json_round_trip_keeps_counts_ids_and_tool_results(exported, tmp_path, embedder):
    src, json_file = exported
    dst = tmp_path / "copy"
    res = import_participant(dst, json_file)
    assert res.participant == "P37" and Bank(dst).participants() == ["P37"]

    assert bank_stats(dst).to_dicts() == bank_stats(src, ["P37"]).to_dicts()
    a, b = dump_participant(Bank(src), "P37"), dump_participant(Bank(dst), "P37")
    assert [t.key for t in a.tables] == [t.key for t in b.tables]
    for ta, tb in zip(a.tables, b.tables):  # every row, every property, every embedding
        assert ta.frame.equals(tb.frame), ta.key
    assert sum(t.frame.height for t in a.tables if t.name == "Segment") == 278
    assert a.migrations == b.migrations

    with MemoryView.open(src, "P37", embedder=embedder) as v1, MemoryView.open(dst, "P37", embedder=embedder) as v2:
        for name, args in TOOL_CALLS:
            r1, r2 = call_tool(v1, name, args).as_json(), call_tool(v2, name, args).as_json()
            assert json.dumps(r1, sort_keys=True) == json.dumps(r2, sort_keys=True), name
            assert r1.get("results") or r1.get("routines") or r1.get("preferences") or r1.get("state_history"), name

    entry, source_entry = Bank(dst).manifest()["participants"]["P37"], Bank(src).manifest()["participants"]["P37"]
    assert {k: entry[k] for k in ("counts", "videos", "consolidated", "inferred")} == \
           {k: source_entry[k] for k in ("counts", "videos", "consolidated", "inferred")}
    assert Bank(dst).manifest()["condition"] == "memora_full"

    again, _ = export_participant(dst, "P37", "json", tmp_path / "again.json")  # the same memory, the same file
    strip = lambda p: [line for line in p.read_text().splitlines() if '"exported_at"' not in line]  # noqa: E731
    assert strip(again) == strip(json_file)


def test_parquet_export_imports_too(small_bank, tmp_path):
    src, _ = small_bank
    out, dump = export_participant(src, "P09", "parquet", tmp_path / "P09.parquet")
    assert out.is_dir() and (out / "export.json").is_file()
    assert len(list(out.glob("*.parquet"))) == len(dump.tables)
    import_participant(tmp_path / "copy", out)
    assert bank_stats(tmp_path / "copy").to_dicts() == bank_stats(src, ["P09"]).to_dicts()


def test_import_builds_the_indexes_the_source_had(small_bank, tmp_path, embedder):
    src, _ = small_bank
    bank = tmp_path / "indexed"
    shutil.copytree(src, bank)
    Bank(bank).build_indexes(["P37"], fts=True)
    out, _ = export_participant(bank, "P37", "json", tmp_path / "P37.json")
    import_participant(tmp_path / "copy", out)
    have = Bank(tmp_path / "copy").manifest()["participants"]["P37"]["indexes"]
    assert have and have == Bank(bank).manifest()["participants"]["P37"]["indexes"]
    with MemoryView.open(bank, "P37", embedder=embedder, config="fts") as v1, \
            MemoryView.open(tmp_path / "copy", "P37", embedder=embedder, config="fts") as v2:
        args = {"query": "wash the bowl"}
        assert call_tool(v1, "search_activities", args) == call_tool(v2, "search_activities", args)


def test_graphml_opens_in_networkx(small_bank, tmp_path):
    src, _ = small_bank
    out, dump = export_participant(src, "P37", "graphml", tmp_path / "p37.graphml")
    g = nx.read_graphml(out)
    assert g.number_of_nodes() == sum(t.frame.height for t in dump.nodes())
    assert g.number_of_edges() == sum(t.frame.height for t in dump.rels())
    seg = g.nodes["P37_102#t0003"]
    assert seg["type"] == "Segment" and seg["turn"] == 3 and "emb" not in seg
    place = next(n for n, a in g.nodes(data=True) if a["type"] == "Place")
    assert isinstance(json.loads(g.nodes[place]["zones"]), list)
    types = {a["type"] for _, _, a in g.edges(data=True)}
    assert {"HAS_SEGMENT", "HAS_STATE", "SUPPORTED_BY", "IN_PLACE"} <= types

    with_emb, _ = export_participant(src, "P37", "graphml", tmp_path / "emb.graphml", embeddings=True)
    assert len(json.loads(nx.read_graphml(with_emb).nodes["P37_102#t0003"]["emb"])) == 384


def test_import_refuses_a_participant_the_bank_holds(exported, tmp_path):
    src, json_file = exported
    bank = tmp_path / "bank"
    shutil.copytree(src, bank)
    before = _snapshot(bank)
    with pytest.raises(BankError, match="already holds participant P37"):
        import_participant(bank, json_file)
    assert _snapshot(bank) == before
    res = invoke("import", bank, json_file)
    assert res.exit_code == 1 and res.output.startswith("Error:") and "already holds participant P37" in res.output
    assert _snapshot(bank) == before


def test_import_refuses_what_is_not_a_memora_export(tmp_path):
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"nodes": [], "edges": []}))
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    for f in (other, text):
        with pytest.raises(DataError, match="not a memora export"):
            import_participant(tmp_path / "bank", f)
    assert not (tmp_path / "bank").exists()


def test_import_refuses_another_embedding_model(exported, tmp_path):
    src, json_file = exported
    bank = tmp_path / "bank"
    export_participant(src, "P09", "json", tmp_path / "P09.json")
    import_participant(bank, tmp_path / "P09.json")
    doc = json.loads(json_file.read_text())
    doc["bank"]["embed_model"] = "some-other-model"
    (tmp_path / "other.json").write_text(json.dumps(doc))
    before = _snapshot(bank)
    with pytest.raises(BankError, match="some-other-model"):
        import_participant(bank, tmp_path / "other.json")
    assert _snapshot(bank) == before and Bank(bank).participants() == ["P09"]


def test_a_damaged_export_leaves_nothing_behind(exported, tmp_path):
    _, json_file = exported
    doc = json.loads(json_file.read_text())
    doc["manifest"]["counts"]["state_events"] += 1  # the file no longer holds what it says
    (tmp_path / "short.json").write_text(json.dumps(doc))
    with pytest.raises(DataError, match="state_events"):
        import_participant(tmp_path / "new-bank", tmp_path / "short.json")
    assert not (tmp_path / "new-bank").exists()

    doc = json.loads(json_file.read_text())
    seg = next(t for t in doc["tables"] if t["table"] == "Segment")
    seg["data"][5][3] = "not a number"  # turn is INT64
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(DataError, match=r"table Segment"):
        import_participant(tmp_path / "new-bank", tmp_path / "bad.json")
    assert not (tmp_path / "new-bank").exists()


def test_cli_export_import_and_help(small_bank, tmp_path):
    src, _ = small_bank
    out = tmp_path / "P09.json"
    res = invoke("export", src, "--participant", "P09", "--out", out)
    assert res.exit_code == 0, res.output
    assert "P09" in res.output and out.is_file()
    assert invoke("export", src, "--participant", "P09", "--out", out).exit_code == 1  # exists: needs --force
    assert invoke("export", src, "--participant", "P09", "--out", out, "--force").exit_code == 0
    res = invoke("import", tmp_path / "copy", out)
    assert res.exit_code == 0, res.output
    assert "imported P09" in res.output
    for cmd in ("export", "import"):
        assert "Examples:" in invoke(cmd, "--help").output

"""Kùzu's optional indexes: a default build makes none, `--fts` / `memora index` add them, and the
recipes that read them say how to get them instead of failing on their first query."""

from __future__ import annotations

import json
import shutil

import pytest
from click.testing import CliRunner

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.retrieve import MemoryView, ToolError, call_tool
from memora_graph.store import index_names

FTS = set(index_names("fts"))


def _indexes(bank, p) -> set[str]:
    with Bank(bank).open(p) as s:
        return set(s.indexes())


@pytest.fixture()
def bank_copy(small_bank, tmp_path):
    path, _ = small_bank
    dst = tmp_path / "bank"
    shutil.copytree(path, dst)
    return dst


def test_default_build_has_no_index_and_fts_recipes_say_how_to_build_them(small_bank, embedder):
    path, result = small_bank
    manifest = Bank(path).manifest()
    assert manifest["indexes"] == {"fts": False, "hnsw": False}
    for p in ("P09", "P37"):
        assert manifest["participants"][p]["indexes"] == []
        assert _indexes(path, p) == set()
    for recipe in ("fts", "kuzu"):
        with pytest.raises(ToolError, match=r"needs the full-text \(FTS\) indexes.*`memora index .* --fts`"):
            MemoryView.open(path, "P37", embedder, config=recipe)
    r = CliRunner().invoke(main, ["tool", str(path), "search", "knife", "--participant", "P37", "--recipe", "fts"])
    assert r.exit_code == 1 and "memora index" in r.output and "--fts" in r.output
    with MemoryView.open(path, "P37", embedder) as view:  # the default recipe needs none
        assert call_tool(view, "search_objects", {"query": "knife"}).results
    # the phase did nothing: the bound is loose, as a loaded machine makes even a no-op take
    # ~10 ms; building the FTS indexes of these two participants takes seconds
    assert result.phases()["indexes (--fts)"] < 0.5


def test_index_command_builds_fts_indexes_and_the_fts_recipe_works(bank_copy, embedder):
    runner = CliRunner()
    r = runner.invoke(main, ["index", str(bank_copy), "--fts", "--participants", "P37"])
    assert r.exit_code == 0, r.output
    assert _indexes(bank_copy, "P37") == FTS and _indexes(bank_copy, "P09") == set()
    manifest = Bank(bank_copy).manifest()
    assert set(manifest["participants"]["P37"]["indexes"]) == FTS
    assert manifest["indexes"]["fts"] is False  # P09 has none yet
    with MemoryView.open(bank_copy, "P37", embedder) as view:  # the index wrote the tool stores again: current
        assert view._persisted is not None
    for recipe in ("fts", "kuzu"):
        with MemoryView.open(bank_copy, "P37", embedder, config=recipe) as view:
            out = call_tool(view, "search_objects", {"query": "knife"})
            assert out.results[0].name == "knife"
            assert out.results[0].score.keyword is not None  # scored by Kùzu's FTS index
    with pytest.raises(ToolError, match="HNSW"):
        MemoryView.open(bank_copy, "P37", embedder, config="hnsw")
    r = runner.invoke(main, ["index", str(bank_copy), "--fts"])  # again: kept, and P09 gets them
    assert r.exit_code == 0, r.output
    assert "(had them)" in r.output
    assert Bank(bank_copy).manifest()["indexes"] == {"fts": True, "hnsw": False}
    r = runner.invoke(main, ["index", str(bank_copy)])
    assert r.exit_code == 2 and "--fts" in r.output


def test_build_with_fts_builds_them(bank_copy, embedder):
    """`memora build --fts` on a built bank (a resume: nothing to rebuild) adds the indexes."""
    r = CliRunner().invoke(main, ["build", str(bank_copy), "--participants", "P09", "--fts", "--quiet"])
    assert r.exit_code == 0, r.output
    assert "full-text indexes" in r.output
    assert _indexes(bank_copy, "P09") == FTS
    assert json.loads((bank_copy / "manifest.json").read_text())["participants"]["P09"]["indexes"] == sorted(FTS)
    with MemoryView.open(bank_copy, "P09", embedder, config="fts") as view:
        assert call_tool(view, "search_activities", {"query": "wash"}).results


def test_build_phases_add_up_to_the_wall_time(small_bank):
    _, result = small_bank
    phases = result.phases()
    assert abs(sum(phases.values()) - result.wall_seconds) < 1e-6
    assert phases["other"] <= 0.05 * result.wall_seconds + 0.5, phases  # nothing big goes untimed
    assert phases["embedding"] > 0 and phases["consolidation + enrichment"] > 0
    assert abs(result.graph_seconds - (result.wall_seconds - phases["embedding"] - phases["load embedding model"])) < 1e-6

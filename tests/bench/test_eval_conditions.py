"""The condition registry and each condition's tools on a small real bank."""

from __future__ import annotations

import pytest

from memora_graph.bench.conditions import (
    BankSet, Condition, ConditionError, get_condition, list_conditions, register, resolve_conditions,
)


def test_seven_conditions_in_the_papers_order():
    assert list_conditions() == ["no_memory", "flat_1d_raw", "flat_1d_edited", "graph_2d_raw", "graph_2d_edited",
                                 "memora_episodic", "memora_full"]
    assert get_condition("MEMORA").name == "memora_full" and get_condition("parametric").name == "no_memory"
    assert get_condition("flat-1d-processed").name == "flat_1d_edited"
    assert "get_routine_skill" in get_condition("memora_full").tools
    assert "get_routine_skill" not in get_condition("memora_episodic").tools
    assert [c.name for c in resolve_conditions("no_memory,memora")] == ["no_memory", "memora_full"]


def test_registry_refuses_duplicates_and_lists_names_on_unknown():
    with pytest.raises(ConditionError, match="frozen|already registered"):
        register(Condition("flat_1d_raw", "x", "flat1d", "raw", (), "flat1d"))
    with pytest.raises(ConditionError, match="known: no_memory, flat_1d_raw"):
        get_condition("flat_3d")


@pytest.mark.parametrize("name", ["flat_1d_raw", "flat_1d_edited", "graph_2d_raw", "graph_2d_edited"])
def test_baseline_tools_on_a_small_bank(name, small_bank, small_raw_bank):
    bank, _ = small_bank
    banks = BankSet(edited=bank, raw=small_raw_bank)
    toolset = get_condition(name).open_tools(banks, "P37")
    assert toolset.participant == "P37"
    assert [s["function"]["name"] for s in toolset.schemas()] == list(get_condition(name).tools)
    out = toolset.call("search", {"query": "wash the plate"}).as_json()
    if name.startswith("flat"):
        assert out["results"] and all(r["video"].startswith("P37_") for r in out["results"])
        assert out["results"] == sorted(out["results"], key=lambda r: -r["similarity"])
    else:
        assert set(out) >= {"activities", "objects", "environment", "patterns"}
        assert out["activities"] and all(len(v) <= 3 for k, v in out.items() if isinstance(v, list))
        assert "_context" in out["activities"][0]
        hist = toolset.call("get_object_history", {"object_query": "plate"}).as_json()
        assert hist["match_type"] in ("exact", "substring", "embedding")
        assert all(h["video"].startswith("P37_") for h in hist["history"])
        t = hist["history"][0]["time"] + 1 if hist["history"] else 5
        state = toolset.call("get_state_at_time", {"time_seconds": t}).as_json()
        assert state["moments"] and all(m["video"].startswith("P37_") for m in state["moments"])
    # cached under the bank and reloaded identically
    path = small_raw_bank if name.endswith("raw") else bank
    assert any((path / ".cache").glob(("flat1d" if name.startswith("flat") else "graph2d") + "-P37-*"))
    again = get_condition(name).open_tools(BankSet(edited=bank, raw=small_raw_bank), "P37").call(
        "search", {"query": "wash the plate"}).as_json()
    assert again == out


def test_raw_memory_keeps_every_observation_and_edited_does_not(small_bank, small_raw_bank):
    from memora_graph.baselines.flat1d import Flat1DMemory
    from memora_graph.baselines.graph2d import Graph2DMemory

    bank, _ = small_bank
    raw, edited = Flat1DMemory.load(small_raw_bank, "P37"), Flat1DMemory.load(bank, "P37")
    assert raw.stats()["state"] > edited.stats()["state"] and raw.stats()["activity"] == edited.stats()["activity"]
    g_raw, g_ed = Graph2DMemory.load(small_raw_bank, "P37"), Graph2DMemory.load(bank, "P37")
    assert g_raw.stats()["object"] > g_ed.stats()["object"]
    assert {"NEXT", "USED_IN", "LOCATED_AT", "CO_OCCURS", "HAPPENED_AT"} <= set(g_ed.stats())


def test_unknown_tool_and_missing_argument_are_observations(small_bank):
    bank, _ = small_bank
    toolset = get_condition("graph_2d_edited").open_tools(BankSet(edited=bank), "P37")
    assert "unknown tool" in toolset.call("get_routine_skill", {"goal_query": "x"}).error
    assert "object_query: Field required" in toolset.call("get_object_history", {}).error


def test_raw_condition_without_a_raw_bank_says_what_to_do(small_bank):
    bank, _ = small_bank
    with pytest.raises(ConditionError, match="--raw-bank"):
        get_condition("flat_1d_raw").open_tools(BankSet(edited=bank), "P37")


@pytest.fixture(scope="session")
def small_episodic_bank(tmp_path_factory, embedder):
    from memora_graph.pipeline import build_bank

    path = tmp_path_factory.mktemp("episodic") / "epi"
    build_bank(path, ["P37"], episodic=True)
    return path


def test_memora_conditions_use_the_typed_tools(small_bank, small_episodic_bank):
    bank, _ = small_bank
    banks = BankSet(edited=bank, episodic=small_episodic_bank)
    full = get_condition("memora_full").open_tools(banks, "P37")
    epi = get_condition("memora_episodic").open_tools(banks, "P37")
    assert {"get_routine_skill", "get_preferences"} <= {s["function"]["name"] for s in full.schemas()}
    assert not {"get_routine_skill", "get_preferences"} & {s["function"]["name"] for s in epi.schemas()}
    out = full.call("search_activities", {"query": "wash the plate", "participant": "P09"}).as_json()
    assert "error" not in out and out["results"]
    assert "P09_" not in str(out)
    assert "unknown tool" in epi.call("get_routine_skill", {"goal_query": "wash"}).error
    assert "time_seconds" in full.call("get_state_at_time", {"time_seconds": "soon"}).error


@pytest.mark.parametrize("family", ["flat1d", "graph2d"])
def test_a_damaged_baseline_cache_is_rebuilt_not_trusted(family, small_bank, tmp_path):
    """Both baselines share one cache-or-build path: a cache whose JSON is cut short is rebuilt
    from the bank (and written whole again), and the memory read back matches the first one."""
    import shutil

    from memora_graph.retrieve.registry import get_family

    src, _ = small_bank
    bank = tmp_path / "bank"
    shutil.copytree(src, bank, ignore=shutil.ignore_patterns(".cache"))
    first = get_family(family).open(bank, "P37").search("wash the plate").model_dump(mode="json")
    (cached,) = (bank / ".cache").glob(f"{family}-P37-*.json")
    cached.write_text(cached.read_text()[:100])  # a write cut short
    again = get_family(family).open(bank, "P37").search("wash the plate").model_dump(mode="json")
    assert again == first
    assert cached.read_text()[:100] != cached.read_text(), "the cache was written whole again"
    assert get_family(family).open(bank, "P37").search("wash the plate").model_dump(mode="json") == first


def test_an_unknown_task_kind_is_refused_before_anything_is_written(small_bank, tmp_path):
    """`--kinds planning` (not a kind) names the kinds there are, instead of a KeyError traceback
    after the run directory was created."""
    from click.testing import CliRunner

    from memora_graph.cli import main

    bank, _ = small_bank
    out = tmp_path / "run"
    res = CliRunner().invoke(main, ["bench", "run", str(bank), "--out", str(out), "--participants", "P37",
                                    "--conditions", "no_memory", "--kinds", "planning"])
    assert res.exit_code == 1 and "unknown task kind(s) planning" in res.output and "eam_qa" in res.output
    assert not out.exists()

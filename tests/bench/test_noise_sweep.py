"""`memora bench noise`: a small sweep end to end (one participant, two rates), its report, resume,
and the break-even arithmetic; the calibration sweep itself is behind `-m slow`."""

from __future__ import annotations

import json
import os

import polars as pl
import pytest

from memora_graph.bank import Bank
from memora_graph.bench.conditions import list_conditions
from memora_graph.bench.noise import break_even, parse_errors, parse_rates, run_noise
from memora_graph.bench.run import run_bench
from memora_graph.errors import MemoraError
from memora_graph.perceive.noise import read_errors


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, tiny_tasks):
    out = tmp_path_factory.mktemp("noise") / "sweep"
    result = run_noise(out, ["P37"], [0.0, 0.3], ["mixed"], tasks=tiny_tasks, seed=2, jobs=1)
    return out, result


def test_a_small_sweep_runs_every_condition_at_every_rate_and_reports(sweep):
    out, result = sweep
    assert [c["cell"] for c in result.cells] == ["clean-0", "mixed-0.3"]
    curves = pl.read_parquet(out / "curves.parquet")
    got = {(r["rate"], r["condition"]) for r in curves.iter_rows(named=True)}
    assert got == {(rate, c) for rate in (0.0, 0.3) for c in list_conditions()}
    report = (out / "report.md").read_text()
    assert "Break-even rate" in report and "repair table" in report
    assert (out / "figures" / "accuracy.png").stat().st_size > 0 and (out / "figures" / "rgp.png").exists()
    assert "mixed" in json.loads((out / "report.json").read_text())["break_even"]
    # a cell's three banks share their segments' texts: the model embeds each list once per cell
    timing = [json.loads(x) for x in (out / "cells" / "clean-0" / "timing.jsonl").read_text().splitlines()]
    assert timing[-1]["texts_spared"] > 0 and timing[-1]["texts_embedded"] > 0


def test_the_clean_cell_is_the_bank_a_plain_build_makes_and_noise_changes_it(sweep, small_bank):
    out, _ = sweep
    clean = Bank(out / "cells" / "clean-0" / "banks" / "edited").manifest()["participants"]["P37"]["counts"]
    plain = Bank(small_bank[0]).manifest()["participants"]["P37"]["counts"]
    assert clean == plain
    assert read_errors(out / "cells" / "clean-0" / "annotations") == []
    noisy = Bank(out / "cells" / "mixed-0.3" / "banks" / "edited").manifest()["participants"]["P37"]["counts"]
    assert noisy != plain


def _vectors(bank) -> dict:
    """Every vector of a bank: its segments' and entities' embeddings as stored, and those a run
    embedded for its corpora (BANK/.cache/embeddings-*.npz), by key."""
    import numpy as np

    out = {}
    with Bank(bank).open("P37") as store:
        for table in ("segment", "entity"):
            out.update({(table, r["id"]): np.asarray(r["emb"]) for r in store.rows(f"_tool_vectors_{table}", participant="P37")})
    for f in sorted((bank / ".cache").glob("embeddings-*.npz")):
        with np.load(f) as data:
            out.update({(f.name, str(k)): data["vectors"][i] for i, k in enumerate(data["keys"])})
    return out


def _same_vectors(a, b) -> bool:
    import numpy as np

    va, vb = _vectors(a), _vectors(b)
    return bool(va) and va.keys() == vb.keys() and all(np.array_equal(va[k], vb[k]) for k in va)


def test_a_cell_gives_the_records_and_vectors_of_banks_built_and_read_one_by_one(sweep, tiny_tasks, tmp_path):
    """The noisy cell is built and read in the process that made the clean cell just before; its
    records and its vectors (bit for bit) are those of its three banks each built in a
    fresh process (`isolate`) and read by a `bench run` with fresh worker processes."""
    from memora_graph.bench.compare import compare_runs
    from memora_graph.bench.noise import BANKS
    from memora_graph.pipeline import build_bank

    out, result = sweep
    assert result.jobs == 1
    cell = out / "cells" / "mixed-0.3"
    for kind, opts in BANKS.items():
        build_bank(tmp_path / kind, ["P37"], annotations=cell / "annotations" / "annotations.csv", isolate=True, **opts)
    run_bench(tmp_path / "edited", tmp_path / "run", participants=["P37"], tasks=tiny_tasks, raw_bank=tmp_path / "raw",
              episodic_bank=tmp_path / "episodic", workers=2)
    cmp = compare_runs(cell / "run", tmp_path / "run")
    assert cmp.rows and cmp.identical, cmp.differences[:5]
    assert {r["condition"] for r in cmp.rows} == set(list_conditions())
    for kind in BANKS:
        assert _same_vectors(cell / "banks" / kind, tmp_path / kind), kind


def test_cells_side_by_side_give_the_same_records(sweep, tiny_tasks, tmp_path):
    """Two worker processes (`jobs=2`), each building and reading a cell in-process: the same
    records and vectors, cell for cell."""
    from memora_graph.bench.compare import compare_runs

    out, _ = sweep
    result = run_noise(tmp_path / "par", ["P37"], [0.0, 0.3], ["mixed"], tasks=tiny_tasks, seed=2, jobs=2)
    assert result.jobs == 2 and [c["cell"] for c in result.cells] == ["clean-0", "mixed-0.3"]
    assert len({c["pid"] for c in result.cells} | {os.getpid()}) >= 2  # not run in the test's process
    for name in ("clean-0", "mixed-0.3"):
        cmp = compare_runs(out / "cells" / name / "run", tmp_path / "par" / "cells" / name / "run")
        assert cmp.identical, (name, cmp.differences[:5])
        for kind in ("edited", "raw", "episodic"):
            assert _same_vectors(out / "cells" / name / "banks" / kind, tmp_path / "par" / "cells" / name / "banks" / kind)
        assert all(json.loads(line)["cpu_seconds"] > 0 for line in
                   (tmp_path / "par" / "cells" / name / "timing.jsonl").read_text().splitlines())


def test_the_repair_table_accounts_for_every_injected_error(sweep):
    out, _ = sweep
    errors = read_errors(out / "cells" / "mixed-0.3" / "annotations")
    table = json.loads((out / "cells" / "mixed-0.3" / "repair.json").read_text())
    for kind, row in table.items():
        assert row["injected"] == sum(e["type"] == kind for e in errors)
        assert row["undone"] + row["worse"] + row["kept"] == row["injected"]
    assert sum(r["injected"] for r in table.values()) == len(errors) > 0


def test_a_second_sweep_resumes_without_running_anything_again(sweep, tiny_tasks):
    out, _ = sweep
    run_noise(out, ["P37"], [0.0, 0.3], ["mixed"], tasks=tiny_tasks, seed=2)
    sessions = json.loads((out / "cells" / "mixed-0.3" / "run" / "manifest.json").read_text())["sessions"]
    assert sessions[-1]["done"] == 0 and sessions[-1]["skipped"] > 0
    with pytest.raises(MemoraError, match="other options"):
        run_noise(out, ["P37"], [0.3], ["mixed"], tasks=tiny_tasks, seed=3)


def test_the_report_leaves_out_a_cell_whose_run_has_not_finished(sweep, tmp_path):
    """A cell writes its repair table after its run: without it, its partial records stay out."""
    import shutil

    from memora_graph.bench.noise import write_noise_report

    out, _ = sweep
    copy = tmp_path / "sweep"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("banks"))
    (copy / "cells" / "mixed-0.3" / "repair.json").unlink()
    write_noise_report(copy)
    assert set(pl.read_parquet(copy / "curves.parquet")["rate"].to_list()) == {0.0}


def test_break_even_interpolates_where_memora_meets_the_best_baselines_clean_accuracy():
    rows = [{"error": "swap", "rate": 0.0, "condition": "memora_full", "accuracy": 60.0},
            {"error": "swap", "rate": 0.0, "condition": "flat_1d_raw", "accuracy": 50.0},
            {"error": "swap", "rate": 0.0, "condition": "graph_2d_edited", "accuracy": 52.0},
            {"error": "swap", "rate": 0.2, "condition": "memora_full", "accuracy": 56.0},
            {"error": "swap", "rate": 0.4, "condition": "memora_full", "accuracy": 48.0}]
    b = break_even(rows, "swap")
    assert b["baseline"] == "graph_2d_edited" and b["rate"] == pytest.approx(0.3)
    assert break_even(rows[:4], "swap")["rate"] is None  # not reached within the rates measured


def test_rates_and_errors_are_checked_by_name():
    assert parse_rates("0.2,0,0.2") == [0.0, 0.2]
    with pytest.raises(MemoraError, match="between 0 and 1"):
        parse_rates("0,2")
    with pytest.raises(MemoraError, match="choose from"):
        parse_errors("mixed,blur")


@pytest.mark.slow
def test_the_calibration_sweep_names_a_break_even_rate_per_error_type(tmp_path):
    """The issue's sweep: P01-P04, five rates, four error types, 17 cells (about 5,400 CPU-s: ~45 min on 2
    idle cores, hours on a busy shared machine; docs/robustness.md)."""
    out = tmp_path / "noise"
    run_noise(out, ["P01", "P02", "P03", "P04"], [0, 0.1, 0.2, 0.3, 0.5], ["mixed", "drop", "swap", "alias"])
    report = json.loads((out / "report.json").read_text())
    assert set(report["break_even"]) == {"mixed", "drop", "swap", "alias"}
    curves = pl.read_parquet(out / "curves.parquet")
    assert curves.filter(pl.col("condition") == "memora_full").height == 4 * 5


def test_the_run_reads_memoras_banks_through_the_tool_stores_a_build_writes(tiny_tasks, tmp_path, monkeypatch):
    """A cell's MEMORA and MEMORA-Episodic banks hold their persisted tool stores, fresh, when its
    run starts (as `memora build` leaves a bank), so the run's views read the segment rows kept
    with them: no segment is looked up in Kùzu one by one (`MemoryView.by_id`)."""
    from memora_graph.bench import noise
    from memora_graph.retrieve.persist import PersistedStores
    from memora_graph.store import Store

    held, lookups = {}, []
    real_run, real_fetch = noise.run_bench, Store.fetch

    def run_checked(bank, out, **kw):
        for kind, path in (("edited", bank), ("episodic", kw["episodic_bank"])):
            b = Bank(path)  # StaleStores (the test fails) when missing or not of this database
            held[kind] = PersistedStores.open(path, "P37", b.checked_sha256("P37"), b.manifest().get("embed_model"))
        return real_run(bank, out, **kw)

    def fetch_counted(self, name, **params):
        if name == "_tool_segment":
            lookups.append(params)
        return real_fetch(self, name, **params)

    monkeypatch.setattr(noise, "run_bench", run_checked)
    monkeypatch.setattr(Store, "fetch", fetch_counted)
    run_noise(tmp_path / "s", ["P37"], [0.0], ["mixed"], tasks=tiny_tasks, seed=2, jobs=1,
              conditions=["memora_full", "memora_episodic"])
    assert set(held) == {"edited", "episodic"}
    records = [json.loads(line) for f in (tmp_path / "s" / "cells" / "clean-0" / "run" / "records").rglob("*.jsonl")
               for line in f.read_text().splitlines()]
    calls = [c for r in records for c in r.get("tool_calls") or () if c.get("name") in ("search", "search_activities")]
    assert calls  # the tools that read segments by id ran
    assert lookups == []

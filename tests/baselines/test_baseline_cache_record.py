"""Baseline caches (BANK/.cache/) are derived files too: read only when their sha256 is the one the
bank's manifest recorded when they were written; an edited one is built again, never read."""

from __future__ import annotations

import json
import shutil

import pytest

from memora_graph.bank import Bank
from memora_graph.baselines.common import EmbeddingStore
from memora_graph.baselines.flat1d import Flat1DMemory
from memora_graph.integrity.verify import verify_bank

P = "P37"


@pytest.fixture()
def bank(small_bank, tmp_path):
    path = tmp_path / "bank"
    shutil.copytree(small_bank[0], path, ignore=shutil.ignore_patterns(".cache"))
    return path


def test_an_edited_baseline_cache_is_built_again_not_read(bank, embedder, caplog):
    first = Flat1DMemory.load(bank, P)
    record = Bank(bank).manifest()["participants"][P]["derived"]["baseline-flat1d"]
    (cached,) = [f for f in (bank / ".cache").glob(f"flat1d-{P}-*.json")]
    assert cached.name in record["files"]
    rows = json.loads(cached.read_text())
    rows[0]["text"] = "forged text"
    cached.write_text(json.dumps(rows))
    report = verify_bank(bank, [P])
    assert not report.ok and any(cached.name in line and "not as recorded" in line for line in report.rows[0]["problems"])
    with caplog.at_level("WARNING", logger="memora_graph.integrity"):
        again = Flat1DMemory.load(bank, P)
    assert any(cached.name in r.getMessage() and "not as recorded" in r.getMessage() for r in caplog.records)
    assert [r.text for r in again.records] == [r.text for r in first.records]
    assert "forged text" not in cached.read_text(), "written again"
    assert verify_bank(bank, [P]).ok
    assert Flat1DMemory.load(bank, P).records[0].text == first.records[0].text


def test_an_edited_embedding_cache_is_not_read(bank, embedder):
    import numpy as np

    store = EmbeddingStore(Bank(bank))
    want = store.encode(["wash the pan"])
    store.save()
    assert Bank(bank).manifest()["derived"][store.path.name]["files"][store.path.name]
    with np.load(store.path) as data:
        keys, mat = data["keys"], data["vectors"].copy()
    mat[:] = 0.5  # forged vectors
    np.savez(store.path, keys=keys, vectors=mat)
    assert any(store.path.name in line for line in verify_bank(bank).bank)
    again = EmbeddingStore(Bank(bank))
    assert again._vectors == {}, "the edited cache was not read"
    assert np.allclose(again.encode(["wash the pan"]), want, atol=1e-5)

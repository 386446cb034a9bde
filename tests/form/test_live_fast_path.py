"""The remember fast path: a remembered segment joins a reader's loaded vectors and keywords in
place (the same answers as loading everything again, the loader's lists untouched), and the live
writer embeds with MiniLM's ONNX export, whose vectors are the PyTorch model's to the 7th digit."""

from __future__ import annotations

import numpy as np
import pytest

from memora_graph.errors import BankError
from memora_graph.retrieve.search import Bm25, VectorTable

TEXTS = ["wash the plate in the sink", "take the knife from the drawer", "put the kettle on the counter",
         "open the fridge", "pour water into the kettle", "cut the onion on the board", "dry the plate",
         "close the drawer", "take milk from the fridge", "rinse the knife"]


def test_appended_rows_answer_as_a_full_load():
    rng = np.random.default_rng(7)
    vecs = rng.normal(size=(len(TEXTS), 16)).astype(np.float32)
    ids = [f"s{i}" for i in range(len(TEXTS))]
    loaded = ids[:4]
    table = VectorTable(loaded, vecs[:4])
    for i in range(4, len(ids)):
        table = table.appended(ids[i], vecs[i])
    full = VectorTable(ids, vecs)
    assert loaded == ids[:4]  # what loaded the table keeps its list
    assert table.ids == ids and len(table) == len(ids)
    assert np.allclose(table.mat, full.mat)
    for q in vecs:
        assert table.topk(q, 5) == full.topk(q, 5)
    assert np.allclose(table.vec("s9"), full.vec("s9"))


def test_added_documents_score_as_a_full_load():
    loaded = [f"s{i}" for i in range(4)]
    bm = Bm25(loaded, TEXTS[:4])
    for i in range(4, len(TEXTS)):
        bm = bm.added(f"s{i}", TEXTS[i])
    full = Bm25([f"s{i}" for i in range(len(TEXTS))], TEXTS)
    assert loaded == [f"s{i}" for i in range(4)]
    assert bm.n == full.n and bm.avg == full.avg and list(bm.lengths) == list(full.lengths)
    for query in ("kettle", "plate sink", "knife drawer", "fridge milk"):
        got, want = bm.search(query, 5), full.search(query, 5)
        assert [i for i, _ in got] == [i for i, _ in want]
        assert np.allclose([s for _, s in got], [s for _, s in want])


def test_live_encoder_is_the_onnx_export_and_agrees_with_torch(monkeypatch):
    from memora_graph.embed import DEFAULT_MODEL, get_embedder
    from memora_graph.form.live import live_embedder

    monkeypatch.delenv("MEMORA_LIVE_ENCODER", raising=False)
    live = live_embedder(DEFAULT_MODEL)
    torch = get_embedder(DEFAULT_MODEL)
    assert live.name == torch.name == DEFAULT_MODEL and live.dim == torch.dim
    assert not getattr(live.inner, "uses_torch")("passage")
    a = np.stack([live.encode([t])[0] for t in TEXTS])
    b = torch.encode(TEXTS)  # as a build embeds: in a batch
    cos = (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    assert cos.min() >= 0.99999
    monkeypatch.setenv("MEMORA_LIVE_ENCODER", "torch")
    assert live_embedder(DEFAULT_MODEL) is torch
    monkeypatch.setenv("MEMORA_LIVE_ENCODER", "gpu")
    with pytest.raises(BankError, match="MEMORA_LIVE_ENCODER"):
        live_embedder(DEFAULT_MODEL)

"""The fast query encoder: ONNX Runtime MiniLM agrees with torch, its export is made once, checked,
redone when damaged, kept out of a read-only home, and a tool call's query never imports torch."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from memora_graph import onnx_embed
from memora_graph.embed import QUERY_ENCODERS, SentenceTransformerEmbedder, SplitEmbedder, get_embedder
from memora_graph.errors import MemoraError
from memora_graph.onnx_embed import VARIANTS, OnnxEmbedder, export_dir, is_valid_export

SENTENCES = ["knife", "bowl", "wash the dishes", "cut vegetables on the board", "where are the knives kept",
             "what happens after washing a plate", "spatula or fork for eggs", "take milk from the fridge",
             "pour water into the kettle", "", ("a considerably longer sentence about putting every clean plate "
                                                "back into the cupboard above the sink once the drying rack is full")]
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def export_root(tmp_path_factory):
    """One export for the whole session (about 20 s); tests copy it where they damage it."""
    root = tmp_path_factory.mktemp("onnx-cache")
    export_dir(root=root)
    return root


@pytest.fixture()
def cache_env(export_root, monkeypatch):
    monkeypatch.setenv("MEMORA_CACHE_DIR", str(export_root))
    return export_root


def _run(code: str, **env) -> str:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=600,
                         check=False, env={**os.environ, "PYTHONPATH": str(REPO), **env})
    assert out.returncode == 0, out.stderr
    return out.stdout


def _copy(src: Path, dst_root: Path) -> Path:
    dst_root.mkdir(parents=True, exist_ok=True)
    return Path(shutil.copytree(src, dst_root / src.name))  # copy2 keeps mtimes: still a valid export


@pytest.mark.parametrize("variant, floor", [("fp32", 0.9999), ("int8", 0.995)])
def test_onnx_vectors_agree_with_torch(export_root, embedder, variant, floor):
    torch_vecs = embedder.inner.passage.encode(SENTENCES, kind="query")
    enc = OnnxEmbedder(variant=variant, root=export_root)
    batch = enc.encode(SENTENCES, kind="query")  # padded batch
    single = np.stack([enc.encode([s], kind="query")[0] for s in SENTENCES])
    for got in (batch, single):
        assert got.shape == torch_vecs.shape and got.dtype == np.float32
        assert np.allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-4)
        assert (got * torch_vecs).sum(1).min() > floor
    assert np.abs(batch - single).max() < 1e-3  # padding does not leak into a sentence's vector


@pytest.mark.parametrize("name, floor", [("onnx", 0.999), ("onnx-int8", 0.97)])
def test_recall_at_10_against_torch_exact_search(small_bank, cache_env, embedder, name, floor):
    from memora_graph.retrieve import MemoryView
    from memora_graph.cli.perf.tools import ACTIVITY_QUERIES, OBJECT_QUERIES, PATTERN_QUERIES

    path, _ = small_bank
    qs = ACTIVITY_QUERIES + OBJECT_QUERIES + PATTERN_QUERIES
    ours = SplitEmbedder(query_encoder=name).encode(qs, kind="query")
    ref = embedder.inner.passage.encode(qs, kind="query")
    recalls = []
    with MemoryView.open(path, "P37") as view:
        for table in ("segment", "entity"):
            vt = view.vectors(table)
            for a, b in zip(ours, ref):
                exact = {i for i, _ in vt.topk(b, 10)}
                recalls.append(len(exact & {i for i, _ in vt.topk(a, 10)}) / len(exact))
    assert np.mean(recalls) >= floor


def test_export_is_made_once_by_concurrent_first_uses_and_reused_without_torch(tmp_path):
    root = tmp_path / "cache"
    code = """
        import sys
        from memora_graph.onnx_embed import export_dir
        d = export_dir()
        print(d, 'torch' in sys.modules)
    """
    procs = [subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(REPO), "MEMORA_CACHE_DIR": str(root)})
             for _ in range(2)]
    outs = [p.communicate(timeout=600)[0].split() for p in procs]
    assert all(p.returncode == 0 for p in procs)
    dirs = {o[0] for o in outs}
    assert len(dirs) == 1, "both processes use one export"
    assert sorted(o[1] for o in outs) == ["False", "True"], "exactly one of them exported (imported torch)"
    exports = [p for p in root.iterdir() if p.is_dir()]
    assert [p.name for p in exports] == [Path(next(iter(dirs))).name]  # no temporary directory left behind
    before = {f.name: f.stat().st_mtime_ns for f in exports[0].iterdir()}

    again = _run("""
        import sys
        from memora_graph.onnx_embed import OnnxEmbedder
        enc = OnnxEmbedder(variant='int8')
        enc.encode(['wash the dishes'])
        print(enc.directory, 'torch' in sys.modules)
    """, MEMORA_CACHE_DIR=str(root)).split()
    assert again == [str(exports[0]), "False"]
    assert {f.name: f.stat().st_mtime_ns for f in exports[0].iterdir()} == before  # reused, not rewritten


def _truncate(d: Path) -> None:
    f = d / VARIANTS["int8"]
    with open(f, "r+b") as fh:
        fh.truncate(f.stat().st_size // 2)


def _overwrite(d: Path) -> None:  # same size, other bytes: only the hash can tell
    f = d / VARIANTS["fp32"]
    with open(f, "r+b") as fh:
        fh.seek(f.stat().st_size // 2)
        fh.write(b"\0" * 4096)


def _no_manifest(d: Path) -> None:  # what a crash before the last step would leave
    (d / "manifest.json").unlink()


def _missing_file(d: Path) -> None:
    (d / VARIANTS["int8"]).unlink()


@pytest.mark.parametrize("damage", [_truncate, _overwrite, _no_manifest, _missing_file])
def test_damaged_or_half_written_exports_are_not_valid(export_root, tmp_path, damage):
    good = next(p for p in export_root.iterdir() if p.is_dir())
    d = _copy(good, tmp_path)
    assert is_valid_export(d)
    damage(d)
    assert not is_valid_export(d)


def test_a_damaged_export_is_redone_not_loaded(export_root, tmp_path, embedder):
    good = next(p for p in export_root.iterdir() if p.is_dir())
    root = tmp_path / "cache"
    d = _copy(good, root)
    _truncate(d)
    killed = root / f".tmp-{d.name}-x1y2z3"  # what an export killed half-way leaves behind
    killed.mkdir()
    (killed / VARIANTS["fp32"]).write_bytes(b"half")
    enc = OnnxEmbedder(variant="int8", root=root)
    assert not killed.exists()
    assert enc.directory == d and is_valid_export(d)
    assert (d / VARIANTS["int8"]).stat().st_size == (good / VARIANTS["int8"]).stat().st_size
    assert json.loads((d / "manifest.json").read_text())["files"][VARIANTS["int8"]]["mtime_ns"] != \
        json.loads((good / "manifest.json").read_text())["files"][VARIANTS["int8"]]["mtime_ns"]  # written anew
    ref = embedder.inner.passage.encode(SENTENCES[:4], kind="query")
    assert (enc.encode(SENTENCES[:4]) * ref).sum(1).min() > 0.995
    assert [p.name for p in root.iterdir() if p.is_dir()] == [d.name]  # the bad copy and the leftover are gone
    assert oct(d.stat().st_mode & 0o777) == oct(0o755)


def test_unwritable_cache_falls_back_to_the_temp_dir_with_a_note(export_root, tmp_path, monkeypatch, caplog):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    monkeypatch.setenv("MEMORA_CACHE_DIR", str(blocker / "cache"))  # cannot be created
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr("tempfile.tempdir", str(tmp))
    fallback = onnx_embed._fallback_root()
    _copy(next(p for p in export_root.iterdir() if p.is_dir()), fallback)  # as if exported there before
    with caplog.at_level("WARNING", logger="memora_graph.onnx_embed"):
        d = export_dir()
    assert d.parent == fallback and is_valid_export(d)
    assert "cannot be written" in caplog.text and str(fallback) in caplog.text
    assert not (blocker / "cache").exists()

    shutil.rmtree(fallback)
    fallback.mkdir()
    fallback.chmod(0o777)  # another user could have planted a model here: not used
    with pytest.raises(onnx_embed.EncoderExportError, match="MEMORA_CACHE_DIR"):
        export_dir()


def test_the_setting_switches_the_query_encoder(cache_env, monkeypatch):
    monkeypatch.setenv("MEMORA_QUERY_ENCODER", "torch")
    split = SplitEmbedder()
    assert split.query_encoder == "torch" and isinstance(split.query, SentenceTransformerEmbedder)
    assert split.query is split.passage  # one torch model, not two
    for name, variant in (("onnx", "fp32"), ("onnx-int8", "int8")):
        monkeypatch.setenv("MEMORA_QUERY_ENCODER", name)
        split = SplitEmbedder()
        assert isinstance(split.query, OnnxEmbedder) and split.query.variant == variant
        assert split._passage is None  # queries alone load no torch model
    monkeypatch.delenv("MEMORA_QUERY_ENCODER")
    assert SplitEmbedder().query_encoder == "onnx-int8"
    assert SplitEmbedder(query_encoder="onnx").query_encoder == "onnx"  # in code, over the environment
    assert get_embedder(query_encoder="torch") is not get_embedder(query_encoder="onnx")
    monkeypatch.setenv("MEMORA_QUERY_ENCODER", "fasttext")
    with pytest.raises(MemoraError, match="unknown query encoder 'fasttext'.*" + ", ".join(QUERY_ENCODERS)):
        SplitEmbedder()
    with pytest.raises(MemoraError, match="default model"):
        SplitEmbedder("intfloat/e5-small-v2", query_encoder="onnx")
    monkeypatch.delenv("MEMORA_QUERY_ENCODER")
    assert SplitEmbedder("intfloat/e5-small-v2").query_encoder == "torch"  # another model: torch both sides


def test_passages_stay_on_torch_and_queries_share_its_space(cache_env, embedder):
    split = SplitEmbedder(query_encoder="onnx-int8")
    p = split.encode(SENTENCES[:4], kind="passage")
    assert isinstance(split._passage, SentenceTransformerEmbedder)
    assert np.allclose(p, embedder.inner.passage.encode(SENTENCES[:4]), atol=1e-6)
    assert (split.encode(SENTENCES[:4], kind="query") * p).sum(1).min() > 0.995


def test_a_tool_call_embeds_its_query_without_importing_torch(small_bank, cache_env):
    path, _ = small_bank
    out = _run(f"""
        import json, sys
        from memora_graph.retrieve import MemoryView, call_tool
        with MemoryView.open({str(path)!r}, 'P37') as view:
            r = call_tool(view, 'search_objects', {{'query': 'bowl'}})
            assert r.results, r
            call_tool(view, 'search_activities', {{'query': 'wash the dishes'}})
            n = view.encoder.misses
        heavy = [m for m in ('torch', 'transformers', 'sentence_transformers') if m in sys.modules]
        print(json.dumps({{'heavy': heavy, 'misses': n}}))
    """, MEMORA_CACHE_DIR=str(cache_env))
    assert json.loads(out) == {"heavy": [], "misses": 2}


def test_cold_calls_embed_their_query_again(small_bank, cache_env):
    """`memora perf tools` clears every query cache before a cold call: the process-wide one too."""
    from memora_graph.embed import CachedEmbedder
    from memora_graph.retrieve import MemoryView, call_tool

    path, _ = small_bank
    emb = CachedEmbedder(SplitEmbedder(query_encoder="onnx-int8"))
    with MemoryView.open(path, "P37", emb) as view:
        call_tool(view, "search_objects", {"query": "bowl"})
        assert emb.encoded == 1
        view.encoder.clear()  # the view's cache only: the process-wide cache still has it
        call_tool(view, "search_objects", {"query": "bowl"})
        assert emb.encoded == 1
        view.encoder.clear(everywhere=True)
        call_tool(view, "search_objects", {"query": "bowl"})
        assert emb.encoded == 2


def test_perf_tools_times_the_encoder_and_measures_its_recall(small_bank, cache_env):
    import polars as pl

    from memora_graph.cli.perf.tools import run_perf

    path, _ = small_bank
    report = run_perf(path, ["P37"], n_queries=2, recipes=["inprocess"], hnsw=False, echo=lambda *_: None)
    enc = report.latency.filter(pl.col("recipe") == "encoder").to_dicts()
    assert len(enc) == 1 and enc[0]["calls"] > 0 and enc[0]["cold_p50_ms"] > 0
    rec = {(r["search"], r["table"]): r["recall@10"] for r in report.recall.to_dicts()}
    name = get_embedder().inner.query_encoder
    assert rec[(f"query encoder {name}", "segment")] >= 0.9
    assert any("tool calls" in line and "top-10 ids differ" in line for line in report.summary)

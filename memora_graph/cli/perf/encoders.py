"""`memora perf encoders`: every query encoder side by side, and the passage side in batches.

Per query encoder (memora_graph/embed.py QUERY_ENCODERS): the import time of what it needs (fresh
processes), model / session load, the one-off ONNX export (into a temporary cache), the latency of
one new query (wall and this thread's CPU time, so that a figure taken on a busy machine can be
told from an idle one), recall@10 of exact search with its vectors against exact search with the
PyTorch query vectors (the space of the bank's passage vectors) over every table the tools search,
and the share of tool calls whose top-10 ids change. Then the passage side: texts per second for
torch and ONNX fp32 in batches of 32 at 1 and 2 threads.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import click
import numpy as np
import polars as pl

from memora_graph.cli.options import output_options
from memora_graph.output import render

_IMPORTS = {"torch": "import torch, sentence_transformers", "onnx": "import onnxruntime, tokenizers"}


def _import_seconds(stmt: str, runs: int = 3) -> float:
    code = f"import time; t = time.perf_counter(); {stmt}; print(time.perf_counter() - t)"
    xs = [float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)
          for _ in range(runs)]
    return statistics.median(xs)


def _pct(xs: list[float], p: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, max(0, round(p * (len(xs) - 1))))]


def _latency(encode, queries: list[str], rounds: int) -> tuple[list[float], list[float]]:
    wall, cpu = [], []
    for _ in range(rounds):
        for q in queries:
            t, c = time.perf_counter(), time.thread_time()
            encode([q])
            cpu.append((time.thread_time() - c) * 1e3)
            wall.append((time.perf_counter() - t) * 1e3)
    return wall, cpu


def _throughput(encode, texts: list[str], runs: int = 3) -> float:
    encode(texts[:32])  # warm-up
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        encode(texts)
        times.append(time.perf_counter() - t)
    return len(texts) / statistics.median(times)


def run_encoder_perf(bank: str | Path, participants: list[str] | None = None, rounds: int = 3, export: bool = True,
                     passages: int = 256, echo=print) -> tuple[pl.DataFrame, pl.DataFrame, list[str]]:
    import torch

    from memora_graph.bank import Bank
    from memora_graph.embed import QUERY_ENCODERS, CachedEmbedder, SentenceTransformerEmbedder, SplitEmbedder
    from memora_graph.onnx_embed import OnnxEmbedder, export_dir
    from memora_graph.cli.perf.tools import benchmark_queries, encoder_agreement
    from memora_graph.retrieve.view import MemoryView

    pids = participants or Bank(bank).participants()
    load_before = os.getloadavg()[0]
    queries = benchmark_queries()
    imports = {k: round(_import_seconds(v), 2) for k, v in _IMPORTS.items()}
    export_s = None
    if export:
        with tempfile.TemporaryDirectory(prefix="memora-export-") as tmp:
            t = time.perf_counter()
            export_dir(root=Path(tmp))
            export_s = time.perf_counter() - t
        echo(f"exported MiniLM to ONNX in a fresh cache in {export_s:.1f} s (this process had torch loaded already)")

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        t = time.perf_counter()
        torch_model = SentenceTransformerEmbedder()
        loads = {"torch": time.perf_counter() - t}
        encoders = {"torch": torch_model}
        for name in QUERY_ENCODERS:
            if name != "torch":
                enc = OnnxEmbedder(variant="int8" if name == "onnx-int8" else "fp32")
                encoders[name], loads[name] = enc, enc.load_seconds
        rows = []
        for name, enc in encoders.items():
            enc.encode(["warm up"], kind="query")
            wall, cpu = _latency(lambda qs, e=enc: e.encode(qs, kind="query"), queries, rounds)
            rows.append({"encoder": name, "import_s": imports["torch" if name == "torch" else "onnx"],
                         "load_s": round(loads[name], 3), "export_s": None if name == "torch" or export_s is None
                         else round(export_s, 1), "query_p50_ms": round(_pct(wall, .5), 2),
                         "query_p95_ms": round(_pct(wall, .95), 2), "cpu_p50_ms": round(_pct(cpu, .5), 2),
                         "cpu_p95_ms": round(_pct(cpu, .95), 2)})
        recall: dict = defaultdict(list)
        agreement = {}
        reference = CachedEmbedder(SplitEmbedder(query_encoder="torch"))
        reference.inner._passage = torch_model  # the models loaded above, not a second copy
        for name in QUERY_ENCODERS:
            if name == "torch":
                continue
            split = SplitEmbedder(query_encoder=name)
            split._passage, split._query = torch_model, encoders[name]
            agreement[name] = encoder_agreement(Path(bank), pids, CachedEmbedder(split), 10, recall, reference)
        for row in rows:
            per_table = [statistics.fmean(v) for (m, _), v in recall.items() if m == f"query encoder {row['encoder']}"]
            row["recall@10"] = round(float(np.mean(per_table)), 4) if per_table else 1.0

        with MemoryView.open(bank, pids[0]) as view:
            texts = [f"{r['summary']} {r['narrative']}" for r in view.fetch("_tool_segment_texts")][:passages]
        fp32 = {n: OnnxEmbedder(variant="fp32", threads=n) for n in (1, 2)}
        batch_rows = []
        for n in (1, 2):
            torch.set_num_threads(n)
            batch_rows.append({"passage encoder": "torch", "threads": n, "batch": 32, "texts": len(texts),
                               "texts_per_s": round(_throughput(torch_model.encode, texts), 1)})
            batch_rows.append({"passage encoder": "onnx fp32", "threads": n, "batch": 32, "texts": len(texts),
                               "texts_per_s": round(_throughput(fp32[n].encode, texts), 1)})
    finally:
        torch.set_num_threads(before)
    notes = [f"{name} vs torch, same tool calls: {line.split('same tool calls: ', 1)[-1].split('; recall@10')[0]}"
             for name, line in agreement.items()]
    notes.append(f"{len(queries)} benchmark queries x {rounds} rounds, each outside every cache; participants "
                 f"{','.join(pids)}; load average {load_before:.2f} before, {os.getloadavg()[0]:.2f} after "
                 f"({os.cpu_count()} cores): wall figures above CPU figures mean the machine was shared")
    return pl.DataFrame(rows), pl.DataFrame(batch_rows), notes


@click.command("encoders")
@click.argument("bank", type=click.Path(exists=True, file_okay=False), default="banks/epic")
@click.option("--participants", default="all", show_default=True, help="Comma-separated ids or 'all'.")
@click.option("--rounds", default=3, show_default=True, help="Passes over the benchmark queries per encoder.")
@click.option("--export/--no-export", default=True, show_default=True,
              help="Also time a first-use ONNX export into a temporary cache (about 20 s).")
@output_options
def perf_encoders_cmd(bank, participants, rounds, export, fmt):
    """Compare the query encoders (MEMORA_QUERY_ENCODER): import, load and export time, latency of
    a new query, recall@10 against PyTorch exact search on BANK; and passage throughput in batches.

    \b
    Examples:
      memora perf encoders banks/epic
      memora perf encoders banks/epic --participants P01,P04 --no-export
    """
    from memora_graph.bank import parse_participants

    pids = parse_participants(participants)
    queries, passages, notes = run_encoder_perf(bank, pids, rounds=rounds, export=export, echo=click.echo)
    click.echo(render(queries, fmt))
    if fmt == "table":
        click.echo(render(passages, fmt))
        for line in notes:
            click.echo(line)


__all__ = ["perf_encoders_cmd", "run_encoder_perf"]

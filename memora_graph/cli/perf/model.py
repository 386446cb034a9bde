"""`memora perf model`: model-backed runs at server speed.

A loopback OpenAI-compatible server (memora_graph/testing/scripted_server.py, in its own process
so that its work is not counted as ours) answers after a configurable latency (0.5 s +- 20% by
default, 64 requests served at once, more queue). Its words are scripted as a function of the
request (memora_graph/testing/responders.py). Against it:

1. the calibration evaluation (P01-P04, the official MEMORA-Bench files bundled in data/) for two
   conditions, at --concurrency 1 and at --concurrency N: wall time, model calls, calls in flight
   at the server (time-weighted mean over the time any was in flight, and max), the speedup, and
   our own overhead per call (client latency minus the time the server held the request);
2. a video build of two synthetic videos at --concurrency 1 and N, and its speedup.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path

import click


@contextmanager
def loopback_server(responder: str, latency: float, jitter: float, slots: int):
    """The scripted server in a child process; yields its base URL."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "memora_graph.testing.scripted_server", "--responder", responder,
         "--latency", str(latency), "--jitter", str(jitter), "--max-concurrency", str(slots)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        if not line.startswith("PORT "):
            raise click.ClickException(f"the loopback server did not start: {line!r}")
        yield f"http://127.0.0.1:{int(line.split()[1])}/v1"
    finally:
        proc.stdin.close()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def server_stats(base_url: str, *, reset: bool = False) -> dict:
    url = f"{base_url}/_stats/reset" if reset else f"{base_url}/_stats"
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    with opener.open(url, timeout=10) as response:
        return json.loads(response.read())


def _overhead_ms(records) -> tuple[float, float, float]:
    """Per call: wall (client latency minus the server's time: ours plus waiting for a core or
    the GIL) mean and median, and the CPU the call took on its thread (ours alone), median."""
    own = [1000 * (r.latency_s - r.server_s) for r in records if r.server_s is not None]
    cpu = [1000 * r.cpu_s for r in records if r.cpu_s is not None]
    nan = float("nan")
    return (statistics.fmean(own) if own else nan, statistics.median(own) if own else nan,
            statistics.median(cpu) if cpu else nan)


def bench_rows(bank: Path, base_url: str, conditions: str, limit: int | None, levels: list[int], tmp: Path,
               participants: list[str]) -> list[dict]:
    from memora_graph.bench.run import run_bench
    from memora_graph.llm import CallLog

    rows = []
    for c in levels:
        out = tmp / f"bench-c{c}"
        server_stats(base_url, reset=True)
        cpu0, t0 = time.process_time(), time.perf_counter()
        summary = run_bench(bank, out, conditions=conditions, participants=participants, backend="openai",
                            backend_options={"base_url": base_url, "model": "scripted-model"}, limit=limit,
                            concurrency=c)
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        stats = server_stats(base_url)
        calls = CallLog.read_jsonl(out / "model_calls.jsonl")
        mean_ms, median_ms, cpu_call_ms = _overhead_ms(calls)
        rows.append({"concurrency": c, "items": summary.done, "failed": summary.failed, "calls": len(calls),
                     "wall_s": wall, "items_s": summary.items_seconds, "inflight_mean": stats["inflight_mean"],
                     "inflight_max": stats["inflight_max"], "overhead_ms_mean": mean_ms,
                     "overhead_ms_median": median_ms, "call_cpu_ms": cpu_call_ms,
                     "cpu_ms_per_call": 1000 * cpu / max(len(calls), 1),
                     "records": out})
    return rows


def video_rows(base_url: str, seconds: float, levels: list[int], tmp: Path) -> list[dict]:
    from memora_graph.testing.synthetic import make_synthetic_video
    from memora_graph.pipeline import build_from_video

    videos = tmp / "videos"
    videos.mkdir(exist_ok=True)
    for name in ("P01_901", "P01_902"):
        make_synthetic_video(videos / f"{name}.mp4", seconds, width=320, height=180, fps=10, preset="ultrafast")
    rows = []
    for c in levels:
        server_stats(base_url, reset=True)
        t0 = time.perf_counter()
        res = build_from_video(tmp / f"video-bank-c{c}", videos, "P01", backend="openai", base_url=base_url,
                               perception_model="scripted-model", concurrency=c)
        wall = time.perf_counter() - t0
        stats = server_stats(base_url)
        rows.append({"concurrency": c, "segments": res.segments, "calls": stats["requests"], "wall_s": wall,
                     "inflight_mean": stats["inflight_mean"], "inflight_max": stats["inflight_max"]})
    return rows


@click.command("model")
@click.option("--bank", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="An edited bank holding P01-P04 (default: built here from the bundled annotations first).")
@click.option("--conditions", default="no_memory,memora_full", show_default=True)
@click.option("--participants", default="P01,P02,P03,P04", show_default=True)
@click.option("--limit", type=int, default=10, show_default=True,
              help="Items per participant and task kind (0: all; the serial run takes 0.5 s per call).")
@click.option("--concurrency", type=int, default=64, show_default=True)
@click.option("--latency", type=float, default=0.5, show_default=True, help="Server seconds per request.")
@click.option("--jitter", type=float, default=0.2, show_default=True, help="+- this fraction of --latency.")
@click.option("--slots", type=int, default=64, show_default=True, help="Requests the server serves at once.")
@click.option("--video-seconds", type=float, default=60.0, show_default=True,
              help="Length of each of the two synthetic videos (0: no video build).")
def perf_model(bank, conditions, participants, limit, concurrency, latency, jitter, slots, video_seconds):
    """The evaluation and a video build against a loopback model server with real latency, at
    --concurrency 1 and N: wall time, calls, calls in flight, speedup, our overhead per call
    (targets: >= 25x at 64, <= 5 ms per call).

    \b
    Example:
      memora perf model --bank banks/cal --limit 10
    """
    from memora_graph.embed import get_embedder

    levels = [1, concurrency]
    pids = [p.strip() for p in participants.split(",") if p.strip()]
    get_embedder().encode(["warm-up"])  # model load and first inference are nobody's per-call cost
    with tempfile.TemporaryDirectory(prefix="memora-perf-model-") as tmp_name:
        tmp = Path(tmp_name)
        if bank is None:
            from memora_graph.pipeline import build_bank

            t0 = time.perf_counter()
            bank = tmp / "bank"
            build_bank(bank, pids)
            click.echo(f"built {bank.name} ({', '.join(pids)}) in {time.perf_counter() - t0:.0f} s")
        click.echo(f"loopback server: {latency:g} s +- {100 * jitter:g}% per request, {slots} at once; "
                   f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
        with loopback_server("memora_graph.testing.responders:agent", latency, jitter, slots) as url:
            rows = bench_rows(bank, url, conditions, limit or None, levels, tmp, pids)
        base = rows[0]
        click.echo(f"\nmemora bench run, {conditions}, {', '.join(pids)}, --limit {limit}: "
                   f"{base['items']} items ({base['failed']} failed)")
        click.echo(f"{'concurrency':>11} {'wall s':>8} {'items s':>8} {'calls':>6} {'in flight mean/max':>19} "
                   f"{'speedup':>8} {'items speedup':>13} {'wall-minus-server ms mean/median':>32} "
                   f"{'call CPU ms':>11} {'process CPU ms/call':>19}")
        for r in rows:
            click.echo(f"{r['concurrency']:>11} {r['wall_s']:>8.1f} {r['items_s']:>8.1f} {r['calls']:>6} "
                       f"{r['inflight_mean']:>12.1f} / {r['inflight_max']:<4} {base['wall_s'] / r['wall_s']:>7.1f}x "
                       f"{base['items_s'] / r['items_s']:>12.1f}x {r['overhead_ms_mean']:>23.2f} / "
                       f"{r['overhead_ms_median']:<6.2f} {r['call_cpu_ms']:>11.2f} {r['cpu_ms_per_call']:>19.1f}")
        click.echo("call CPU ms: the median CPU one model call takes on its own thread (request, client, parsing, "
                   "validation, log): our overhead, excluding the server; wall-minus-server adds waiting for a core "
                   "and the GIL; process CPU includes the memory tools and the run's setup")
        same = _same_records(rows[0]["records"], rows[-1]["records"])
        click.echo(f"records identical to --concurrency 1 (timings aside): {same}")
        if video_seconds:
            with loopback_server("memora_graph.testing.responders:video", latency, jitter, slots) as url:
                vrows = video_rows(url, video_seconds, levels, tmp)
            click.echo(f"\nmemora build --video: two synthetic videos of {video_seconds:g} s, one participant, "
                       "LLM consolidation")
            for r in vrows:
                click.echo(f"{r['concurrency']:>11} {r['wall_s']:>8.1f} s {r['calls']:>5} calls, in flight "
                           f"{r['inflight_mean']:.1f} / {r['inflight_max']}, {vrows[0]['wall_s'] / r['wall_s']:.2f}x")


def _same_records(a: Path, b: Path) -> bool:
    def load(root: Path) -> dict:
        out = {}
        for path in sorted((root / "records").rglob("*.jsonl")):
            recs = []
            for line in path.read_text().splitlines():
                r = json.loads(line)
                r.pop("time", None)
                for c in r.get("tool_calls") or []:
                    c.pop("seconds", None)
                recs.append(r)
            out[str(path.relative_to(root))] = recs
        return out

    return load(a) == load(b)

"""Benchmarks of the video path that print figures (`memora perf decode`, `memora perf video`).

`decode`: decode and segment a synthetic video, reported as a multiple of real time.
`video`: a whole build from a synthetic video against a scripted OpenAI-compatible server on
127.0.0.1 (the test suite's), reporting the work per segment other than waiting for the model.
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import click
import numpy as np

from memora_graph.testing.synthetic import make_synthetic_video, scripted_perception


@click.command("decode")
@click.option("--seconds", default=60.0, show_default=True, help="Length of the synthetic video.")
@click.option("--size", default="1280x720", show_default=True, help="WIDTHxHEIGHT of the synthetic video.")
@click.option("--fps", default=30, show_default=True)
@click.option("--video", "video_path", type=click.Path(dir_okay=False), help="Decode this file instead (or keep the synthetic one here).")
@click.option("--repeat", default=3, show_default=True)
@click.option("--fast", is_flag=True, help="Also skip the deblocking filter.")
def perf_decode(seconds, size, fps, video_path, repeat, fast):
    """Decode and segment a 60 s synthetic video; print the multiple of real time (target >= 20x).

    \b
    Example:
      memora perf decode
      memora perf decode --size 1920x1080 --fps 50
    """
    from memora_graph.perceive.video import DecodeOptions, probe_video, segment_video

    width, height = (int(x) for x in size.lower().split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(video_path) if video_path else Path(tmp) / "synthetic.mp4"
        if not path.exists():
            t0 = time.perf_counter()
            make_synthetic_video(path, seconds, width=width, height=height, fps=fps)
            click.echo(f"wrote {path.name}: {seconds:g} s {width}x{height} {fps} fps H.264 + AAC in {time.perf_counter() - t0:.1f} s")
        info = probe_video(path)
        opts = DecodeOptions(skip_loop_filter=fast)
        runs, cpu = [], []
        for _ in range(repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            clips = list(segment_video(path, opts, info=info))
            runs.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        frames = sum(len(c.frames) for c in clips)
        best, median = min(runs), statistics.median(runs)
        click.echo(f"{info.duration:.1f} s {info.width}x{info.height} {info.fps:g} fps {info.codec}: {len(clips)} clips, "
                   f"{frames} frames ({clips[0].frames[0].width}x{clips[0].frames[0].height} JPEG), "
                   f"audio {sum(c.audio_samples for c in clips)} samples")
        click.echo(f"decode+segment: median {median:.2f} s, best {best:.2f} s over {repeat} runs = "
                   f"{info.duration / median:.1f}x real time (best {info.duration / best:.1f}x); "
                   f"CPU time {statistics.median(cpu):.2f} s (all threads; on a busy machine wall time also counts "
                   f"waiting for a core: load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)")


def _support_server():
    """The scripted OpenAI-compatible server the tests use (memora_graph/testing/scripted_server.py)."""
    from memora_graph.testing.scripted_server import ScriptedServer, Turn

    return ScriptedServer, Turn


@click.command("video")
@click.option("--seconds", default=600.0, show_default=True, help="Length of the synthetic video (60 segments).")
@click.option("--objects", default=8, show_default=True, help="Objects per perceived segment.")
def perf_video(seconds, objects):
    """Build from a synthetic video against a scripted server on 127.0.0.1 and print the graph
    work per segment: everything except decoding and waiting for the model (target <= 50 ms).

    \b
    Example:
      memora perf video
    """
    from memora_graph.embed import get_embedder
    from memora_graph.pipeline import build_from_video

    ScriptedServer, Turn = _support_server()
    n = int(np.ceil(seconds / 10))
    usage = {"prompt_tokens": 3000, "completion_tokens": 600}
    script = [Turn(content=json.dumps(scripted_perception(i, objects)), usage=usage) for i in range(n)]
    # The editor answers ADD for everything: the repairs turn re-sightings into UPDATE / NOOP.
    groups = objects + 1
    script += [Turn(content=json.dumps({"object_operations": [
        {"event": "ADD", "observation": g, "object_id": "new", "data": {"name": "x"}, "reason": "seen"}
        for g in range(groups)]}), usage={"prompt_tokens": 900, "completion_tokens": 200}) for _ in range(n)]
    t0 = time.perf_counter()
    get_embedder().encode(["warm-up"])  # model load and first inference are not per-segment work
    warm = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp, ScriptedServer(script) as server:
        video = make_synthetic_video(Path(tmp) / "kitchen.mp4", seconds, width=320, height=180, fps=10, preset="ultrafast")
        res = build_from_video(Path(tmp) / "bank", video, "P01", backend="openai", base_url=server.base_url,
                               perception_model="scripted-vlm", backend_options={"max_retries": 0})
    segs = max(res.segments, 1)
    t = res.timings
    graph = res.graph_seconds
    other = graph - t.editor - t.embedding - t.graph - res.finish_seconds

    def ms(x):
        return f"{1000 * x / segs:.1f}"

    click.echo(f"{res.segments} segments, {len(res.calls)} model calls, entities {res.counts.get('entities')}, "
               f"state events {res.counts.get('state_events')}, places {res.counts.get('places')} "
               f"(embedding model loaded and warmed up beforehand in {warm:.1f} s)")
    click.echo(f"wall {res.wall_seconds:.2f} s = decode {res.decode_seconds:.2f} + waiting for the model "
               f"{res.model_seconds:.2f} + graph work {graph:.2f} + offline consolidation {res.inferred_seconds:.2f} "
               f"(once per participant, {ms(res.inferred_seconds)} ms per segment here)")
    click.echo(f"graph work per segment: {ms(graph)} ms (target <= 50 ms) = editor {ms(t.editor)} + embedding "
               f"{ms(t.embedding)} + staging {ms(t.graph)} + bulk load {ms(res.finish_seconds)} + other {ms(other)} "
               f"(probe, opening the database, prompts and reply parsing)")

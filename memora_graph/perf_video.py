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


def make_synthetic_video(path: str | Path, seconds: float, *, width: int = 320, height: int = 240, fps: int = 25,
                         audio: bool = True, tone_hz: float = 440.0, audio_rate: int = 44100,
                         preset: str = "veryfast") -> Path:
    """Write an H.264/AAC MP4 of generated frames and a sine tone. The red channel of every
    frame is round(255 * t / seconds), so a decoded frame tells the time it was taken at."""
    import av

    path = Path(path)
    n = int(round(seconds * fps))
    yy, xx = np.mgrid[0:height, 0:width]
    texture = ((xx // 8 + yy // 8) % 64).astype(np.uint8)
    with av.open(str(path), "w") as out:
        vs = out.add_stream("libx264", rate=fps)
        vs.width, vs.height, vs.pix_fmt = width, height, "yuv420p"
        vs.options = {"preset": preset, "g": str(2 * fps)}
        as_ = None
        if audio:
            as_ = out.add_stream("aac", rate=audio_rate)
            as_.layout = "stereo"
        img = np.empty((height, width, 3), np.uint8)
        img[..., 2] = 96
        for i in range(n):
            img[..., 0] = round(255 * (i / fps) / seconds)
            img[..., 1] = texture + np.uint8(i % 192)  # motion, so the encoder has real work
            frame = av.VideoFrame.from_ndarray(img, format="rgb24")
            frame.pts = i
            out.mux(vs.encode(frame))
        out.mux(vs.encode())
        if as_ is not None:
            total, chunk, s = int(seconds * audio_rate), 1024, 0
            while s < total:
                k = min(chunk, total - s)
                wave_ = (0.3 * np.sin(2 * np.pi * tone_hz * np.arange(s, s + k) / audio_rate)).astype(np.float32)
                af = av.AudioFrame.from_ndarray(np.stack([wave_, wave_]), format="fltp", layout="stereo")
                af.sample_rate, af.pts = audio_rate, s
                out.mux(as_.encode(af))
                s += k
            out.mux(as_.encode())
    return path


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
    """The scripted OpenAI-compatible server (memora_graph.testing): real HTTP, scripted words."""
    from memora_graph.testing.scripted_server import ScriptedServer, Turn

    return ScriptedServer, Turn


BENCH_OBJECTS = ("plate", "mug", "knife", "cutting_board", "pan", "sponge", "kettle", "spoon", "bowl", "glass",
                 "towel", "lid")


def scripted_perception(turn: int, n_objects: int = 8) -> dict:
    """A plausible perception reply for benchmark turn `turn` (objects move between places)."""
    places = ["counter_area", "sink_area", "stove_area", "fridge_area"]
    objects = {}
    for k in range(n_objects):
        loc = places[(k + turn) % len(places)]
        objects[BENCH_OBJECTS[k % len(BENCH_OBJECTS)]] = {
            "name": BENCH_OBJECTS[k % len(BENCH_OBJECTS)].replace("_", " "), "first_seen": 1.0,
            "visual_properties": {"color": "red" if k % 2 else "white"},
            "spatial_info": {"location": loc, "movement_trajectory": f"{places[(k + turn - 1) % 4]} -> {loc}" if k % 3 == 0 else None},
            "state": {"current_state": "clean" if turn % 2 else "dirty", "held_by": "right hand" if k == 0 else None},
        }
    objects["sink"] = {"name": "sink", "is_fixture": True, "spatial_info": {"location": "sink_area"}}
    return {
        "environment": {"layout_description": "a small kitchen", "location_id": places[turn % 4],
                        "zones": {"sink": {"anchor": "sink", "position": "sink_area", "contents": [BENCH_OBJECTS[1]]}},
                        "spatial_relations": [f"{BENCH_OBJECTS[1]} ADJACENT_TO sink"]},
        "activity_narrative": {"summary": f"turn {turn}: moving things around the kitchen",
                               "action_breakdown": [{"timestamp": 2.0 * i, "action": "move", "object": BENCH_OBJECTS[i]}
                                                    for i in range(4)]},
        "object_registry": objects,
    }


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
                               perception_model="scripted-vlm", backend_options={"backoff_s": 0})
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

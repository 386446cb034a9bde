"""Synthetic inputs the video tests and benchmarks share: a generated MP4 whose frames tell their
own time (`make_synthetic_video`), and a plausible perception reply for a scripted model server
(`scripted_perception`, what `responders.video` answers)."""

from __future__ import annotations

from pathlib import Path

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

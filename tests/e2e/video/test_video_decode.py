"""Decoding a real (synthetic) video with PyAV: clips, frame sampling, timestamps, audio, errors."""

from __future__ import annotations

import io
import wave

import av
import numpy as np
import pytest
from e2e.conftest import SHORT_SECONDS, TONE_HZ

from memora_graph.errors import DataError
from memora_graph.perceive.video import DecodeOptions, list_videos, probe_video, segment_video


def _jpeg_red(jpeg: bytes) -> float:
    """Mean red value of a JPEG, decoded with FFmpeg's mjpeg decoder."""
    ctx = av.CodecContext.create("mjpeg", "r")
    frames = list(ctx.decode(av.Packet(jpeg)))
    return float(frames[0].to_ndarray(format="rgb24")[..., 0].mean())


def test_clips_frames_timestamps_and_audio(short_video):
    info = probe_video(short_video)
    assert info.video_id == "kitchen" and info.has_audio
    assert info.duration == pytest.approx(SHORT_SECONDS, abs=0.15)
    clips = list(segment_video(short_video, DecodeOptions(audio=True)))
    assert [(c.turn_id, c.t_start) for c in clips] == [(0, 0.0), (1, 10.0), (2, 20.0)]
    assert [c.t_end for c in clips][:2] == [10.0, 20.0] and clips[2].t_end == pytest.approx(SHORT_SECONDS, abs=0.15)
    # 2 fps: 20 frames per full 10 s clip, 6 for the 3 s tail, at 0, 0.5, 1.0 ... s into the clip
    assert [len(c.frames) for c in clips] == [20, 20, 6]
    for c in clips:
        assert [f.t_rel for f in c.frames] == pytest.approx([0.5 * i for i in range(len(c.frames))], abs=0.11)
        assert all(f.t == pytest.approx(c.t_start + f.t_rel, abs=1e-6) for f in c.frames)
        assert all(f.jpeg[:2] == b"\xff\xd8" and f.jpeg[-2:] == b"\xff\xd9" for f in c.frames)
    # the frame at 15 s really is the one taken at 15 s (its red channel encodes the time)
    f15 = clips[1].frames[10]
    assert _jpeg_red(f15.jpeg) == pytest.approx(255 * f15.t / SHORT_SECONDS, abs=6)
    # mono 16 kHz 16-bit WAV per clip, as long as the clip, carrying the 440 Hz tone
    for c in clips:
        with wave.open(io.BytesIO(c.audio_wav)) as w:
            assert (w.getnchannels(), w.getframerate(), w.getsampwidth()) == (1, 16000, 2)
            pcm = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2").astype(np.float32)
        assert c.audio_samples == len(pcm)
        assert len(pcm) == pytest.approx(16000 * c.seconds, rel=0.01)
        spectrum = np.abs(np.fft.rfft(pcm))
        peak_hz = np.argmax(spectrum[1:]) * 16000 / len(pcm) + 16000 / len(pcm)
        assert peak_hz == pytest.approx(TONE_HZ, abs=3)


def test_frame_cap_downscale_and_audio_off(hd_video):
    clips = list(segment_video(hd_video, DecodeOptions(fps=5, max_frames=12, audio=False)))
    assert len(clips) == 1 and clips[0].audio_wav is None
    frames = clips[0].frames
    assert len(frames) == 12  # 4 s at 5 fps would be 20: capped, spread over the clip
    assert frames[0].t_rel == 0.0 and frames[-1].t_rel > 3.0
    assert all(b.t > a.t for a, b in zip(frames, frames[1:]))
    assert (frames[0].width, frames[0].height) == (640, 360)


def test_a_video_directory_is_every_video_in_it(tmp_path, short_video):
    (tmp_path / "b.mp4").write_bytes(short_video.read_bytes())
    (tmp_path / "a.MOV").write_bytes(short_video.read_bytes())
    (tmp_path / "notes.txt").write_text("not a video")
    assert [p.name for p in list_videos(tmp_path)] == ["a.MOV", "b.mp4"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="no video files"):
        list_videos(tmp_path / "empty")


@pytest.mark.parametrize("kind", ["empty", "garbage", "truncated", "audio_only", "text"])
def test_unreadable_files_fail_clearly(tmp_path, short_video, kind):
    path = tmp_path / f"{kind}.mp4"
    if kind == "empty":
        path.write_bytes(b"")
    elif kind == "garbage":
        path.write_bytes(np.random.default_rng(0).integers(0, 256, 50_000, dtype=np.uint8).tobytes())
    elif kind == "truncated":
        path.write_bytes(short_video.read_bytes()[: short_video.stat().st_size // 2])
    elif kind == "text":
        path.write_text("hello, this is not a video\n" * 100)
    else:
        with av.open(str(path), "w") as out:
            s = out.add_stream("aac", rate=16000)
            s.layout = "mono"
            frame = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp", layout="mono")
            frame.sample_rate = 16000
            out.mux(s.encode(frame))
            out.mux(s.encode())
    with pytest.raises(DataError) as err:
        probe_video(path)
    assert str(path) in str(err.value)
    assert {"empty": "empty file", "audio_only": "no video stream"}.get(kind, "not a readable video") in str(err.value)


def test_a_truncated_stream_is_caught_before_and_while_decoding(tmp_path):
    from memora_graph.testing.synthetic import make_synthetic_video

    whole = make_synthetic_video(tmp_path / "whole.mkv", SHORT_SECONDS, width=160, height=120, fps=10)
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])  # the header still claims 23 s
    with pytest.raises(DataError, match="truncated"):
        probe_video(cut)  # the packet scan sees the stream end early
    clips = segment_video(cut, info=probe_video(cut, scan=False))
    assert next(clips).turn_id == 0  # the clips before the damage decode ...
    with pytest.raises(DataError, match=r"cut\.mkv: no video frames after"):
        list(clips)  # ... and the damage is an error, not silently empty clips

"""Video decoding for the perception processor: a file -> non-overlapping 10 s clips.

Each clip carries frames sampled at 2 fps (at most 24), downscaled and JPEG-encoded, and the
clip's audio as mono 16 kHz WAV for audio-capable models (the paper's perception
preprocessing). One streaming pass over the file: memory stays bounded by one clip, however
long the video. Files are probed (opened, a frame decoded) before a build writes anything, so
a corrupt, empty or unsupported file fails with a `DataError` naming it and the bank untouched.
"""

from __future__ import annotations

import bisect
import io
import math
import re
import wave
from collections.abc import Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from memora_graph.errors import DataError
from memora_graph.perceive.bounds import seconds_problem

VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".mkv", ".webm", ".avi", ".mpg", ".mpeg", ".ts", ".mts")
_VIDEO_ID = re.compile(r"[^A-Za-z0-9_.-]+")
MIN_TAIL_S = 1.0  # containers often run a frame past a round length (20.02 s): no 0.02 s turn


@dataclass(frozen=True)
class DecodeOptions:
    segment_seconds: float = 10.0
    fps: float = 2.0  # frames sampled per second of video
    max_frames: int = 24  # per segment
    max_side: int = 640  # longest side of a sampled frame, in pixels
    jpeg_quality: int = 4  # mjpeg qscale: 2 (best) .. 31 (worst)
    audio: bool = True
    audio_rate: int = 16000
    skip_nonref: bool = True  # do not decode frames no other frame depends on (faster)
    skip_loop_filter: bool = False  # skip H.264/HEVC deblocking (faster; slight blocking on heavy compression)

    def __post_init__(self):
        if self.segment_seconds <= 0 or self.fps <= 0 or self.max_frames < 1 or self.max_side < 16:
            raise ValueError("segment_seconds and fps must be > 0, max_frames >= 1, max_side >= 16")


@dataclass
class ClipFrame:
    t: float  # seconds from the start of the video
    t_rel: float  # seconds from the start of the clip
    jpeg: bytes
    width: int
    height: int


@dataclass
class VideoClip:
    """One 10 s turn of a video, as the perception model receives it."""

    video_id: str
    turn_id: int
    t_start: float
    t_end: float
    frames: list[ClipFrame] = field(default_factory=list)
    audio_wav: bytes | None = None  # mono 16-bit PCM WAV, None without an audio track or with audio off
    audio_samples: int = 0

    @property
    def seconds(self) -> float:
        return self.t_end - self.t_start


@dataclass(frozen=True)
class VideoInfo:
    path: Path
    video_id: str
    duration: float
    fps: float
    width: int
    height: int
    codec: str
    has_audio: bool

    def n_segments(self, segment_seconds: float = 10.0) -> int:
        """Clips of the video; a final remainder under MIN_TAIL_S is not a turn of its own."""
        return max(1, math.ceil((self.duration - MIN_TAIL_S) / segment_seconds - 1e-9))


def _av():
    try:
        import av
    except ImportError:
        raise DataError("video input needs PyAV: pip install 'memora-graph[video]'") from None
    av.logging.set_level(av.logging.PANIC)  # decoder chatter on stderr; errors still raise
    return av


def video_id_for(path: str | Path) -> str:
    """The video id a file gets by default: its name without the suffix."""
    return _VIDEO_ID.sub("_", Path(path).stem) or "video"


def list_videos(path: str | Path) -> list[Path]:
    """A video file, or every video file (by suffix) directly inside a directory, sorted."""
    p = Path(path)
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in VIDEO_SUFFIXES)
        if not files:
            raise DataError(f"{p}: no video files here (looked for {', '.join(VIDEO_SUFFIXES)})")
        return files
    if not p.exists():
        raise DataError(f"{p}: no such file or directory")
    return [p]


def probe_video(path: str | Path, video_id: str | None = None, scan: bool = True) -> VideoInfo:
    """Open the file, decode its first frame and (with `scan`) read every packet header to make
    sure the stream reaches the duration the container claims (a truncated download does not).
    A DataError names the file if any of that fails."""
    av = _av()
    path = Path(path)
    if path.is_file() and path.stat().st_size == 0:
        raise DataError(f"{path}: empty file (0 bytes), not a video")
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise DataError(f"{path}: has no video stream (an audio or data file?)")
            stream = container.streams.video[0]
            first = next(container.decode(stream), None)
            if first is None:
                raise DataError(f"{path}: the video stream has no decodable frame (empty or truncated file)")
            duration = _duration(container, stream)
            if not duration > 0:  # (NaN too)
                raise DataError(f"{path}: cannot tell the video's duration (damaged container?)")
            if seconds_problem(duration):  # infinite, or longer than the stated range (perceive/bounds.py)
                raise DataError(f"{path}: field 'duration': {seconds_problem(duration)} (the container says "
                                f"{duration:g} s)")
            if scan:
                _check_complete(container, stream, duration, path)
            rate = stream.average_rate or stream.guessed_rate
            return VideoInfo(
                path=path, video_id=video_id or video_id_for(path), duration=duration,
                fps=float(rate) if rate else 0.0, width=first.width, height=first.height,
                codec=stream.codec_context.name, has_audio=bool(container.streams.audio),
            )
    except DataError:
        raise
    except (av.FFmpegError, OSError, StopIteration, ValueError) as exc:
        raise DataError(f"{path}: not a readable video ({_reason(exc)})") from None


def _check_complete(container, stream, duration: float, path: Path) -> None:
    """Demux (no decoding: fast) to the end; the last packet must be near the claimed end."""
    container.seek(0)
    tb = float(stream.time_base)
    start = float(stream.start_time * stream.time_base) if stream.start_time is not None else 0.0
    last = 0.0
    for packet in container.demux(stream):
        if packet.pts is not None:
            last = max(last, packet.pts * tb - start)
    if last < duration - max(1.0, 0.02 * duration):
        raise DataError(f"{path}: the video stream ends at {last:.1f} s but the file says it lasts {duration:.1f} s "
                        f"(truncated or damaged)")


def _duration(container, stream) -> float:
    if stream.duration is not None and stream.time_base is not None:
        return float(stream.duration * stream.time_base)
    if container.duration is not None:
        return container.duration / 1_000_000  # microseconds (AV_TIME_BASE)
    return 0.0


def _reason(exc: Exception) -> str:
    text = str(exc)
    return text.split(": '", 1)[0] if text else type(exc).__name__


def _targets(t0: float, t1: float, opts: DecodeOptions) -> list[float]:
    """Sample times of one clip: every 1/fps seconds, evenly thinned to max_frames."""
    n = max(1, math.ceil((t1 - t0) * opts.fps - 1e-9))
    times = [t0 + i / opts.fps for i in range(n)]
    if len(times) > opts.max_frames:
        step = len(times) / opts.max_frames
        times = [times[int(i * step)] for i in range(opts.max_frames)]
    return times


class _JpegEncoder:
    """Downscale and JPEG-encode frames with FFmpeg's mjpeg encoder (no imaging library)."""

    def __init__(self, av, width: int, height: int, opts: DecodeOptions):
        scale = min(1.0, opts.max_side / max(width, height))
        self.width = max(2, int(width * scale) // 2 * 2)
        self.height = max(2, int(height * scale) // 2 * 2)
        ctx = av.CodecContext.create("mjpeg", "w")
        ctx.width, ctx.height, ctx.pix_fmt = self.width, self.height, "yuvj420p"
        ctx.time_base = Fraction(1, 1000)
        ctx.options = {"qmin": str(opts.jpeg_quality), "qmax": str(opts.jpeg_quality)}
        self.ctx = ctx
        self._pts = 0

    def encode(self, frame) -> bytes:
        small = frame.reformat(width=self.width, height=self.height, format="yuvj420p", interpolation="AREA")
        small.pts, small.time_base = self._pts, self.ctx.time_base  # else PyAV rescales pts to 0
        self._pts += 1
        return b"".join(bytes(p) for p in self.ctx.encode(small))


def _wav(samples: np.ndarray, rate: int) -> bytes:
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(samples.astype("<i2", copy=False).tobytes())
    return buf.getvalue()


def segment_video(path: str | Path, options: DecodeOptions | None = None, video_id: str | None = None,
                  info: VideoInfo | None = None) -> Iterator[VideoClip]:
    """Yield the video's clips in order. Decoding errors mid-file raise a DataError naming the
    file and the time reached (a truncated file still yields the clips before the damage)."""
    av = _av()
    opts = options or DecodeOptions()
    info = info or probe_video(path, video_id)
    vid = video_id or info.video_id
    seg = opts.segment_seconds
    n_seg = info.n_segments(seg)
    bounds = [(i * seg, min((i + 1) * seg, info.duration)) for i in range(n_seg)]
    targets = [_targets(a, b, opts) for a, b in bounds]
    frames: dict[int, list[ClipFrame]] = {i: [] for i in range(n_seg)}
    audio: dict[int, list[np.ndarray]] = {i: [] for i in range(n_seg)}
    next_target = [0] * n_seg
    emitted = 0
    reached = 0.0
    try:
        container = av.open(str(info.path))
    except (av.FFmpegError, OSError) as exc:
        raise DataError(f"{info.path}: not a readable video ({_reason(exc)})") from None
    with container:
        vstream = container.streams.video[0]
        vstream.thread_type = "AUTO"  # frame threads: both cores decode
        if opts.skip_nonref:
            # Frames nothing else references (most B-frames) are never needed to decode others;
            # at 2 fps sampling the next decoded frame is a few ms away, and its time is recorded.
            vstream.codec_context.skip_frame = "NONREF"
        if opts.skip_loop_filter:
            vstream.codec_context.options = {"skip_loop_filter": "all"}
        vtb = float(vstream.time_base)
        v0 = float(vstream.start_time * vstream.time_base) if vstream.start_time is not None else 0.0
        astream = container.streams.audio[0] if (opts.audio and container.streams.audio) else None
        resampler = av.AudioResampler(format="s16", layout="mono", rate=opts.audio_rate) if astream else None
        a0 = float(astream.start_time * astream.time_base) if astream is not None and astream.start_time is not None else v0
        cutter = _AudioCutter(a0 - v0, bounds, opts.audio_rate, audio) if astream is not None else None
        encoder: _JpegEncoder | None = None
        v_t = 0.0

        def clip(i: int) -> VideoClip:
            chunks = audio.pop(i)
            wav = samples = None
            if astream is not None:
                pcm = np.concatenate(chunks) if chunks else np.zeros(0, np.int16)
                samples = len(pcm)
                wav = _wav(pcm, opts.audio_rate)
            return VideoClip(vid, i, bounds[i][0], bounds[i][1], frames.pop(i), wav, samples or 0)

        def ready() -> Iterator[VideoClip]:
            nonlocal emitted
            # Clips wait for both streams; an audio track that ends early stops holding them.
            watermark = v_t if cutter is None or v_t - cutter.t > 3 * seg else min(v_t, cutter.t)
            while emitted < n_seg and bounds[emitted][1] <= watermark:
                yield clip(emitted)
                emitted += 1

        streams = [vstream] + ([astream] if astream is not None else [])
        try:
            for packet in container.demux(*streams):
                for decoded in packet.decode():
                    if packet.stream is vstream:
                        if decoded.pts is None:
                            continue
                        t = decoded.pts * vtb - v0
                        v_t = max(v_t, t)
                        i = min(int(t // seg), n_seg - 1)
                        tl = targets[i]
                        k = next_target[i]
                        if k < len(tl) and t + 1e-3 >= tl[k]:
                            if encoder is None:
                                encoder = _JpegEncoder(av, decoded.width, decoded.height, opts)
                            frames[i].append(ClipFrame(round(t, 3), round(t - bounds[i][0], 3), encoder.encode(decoded),
                                                       encoder.width, encoder.height))
                            while k < len(tl) and tl[k] <= t + 1e-3:
                                k += 1  # a frame covers every target it reached (gaps, low-fps input)
                            next_target[i] = k
                    else:
                        for out in resampler.resample(decoded):
                            cutter.add(out)
                reached = max(reached, v_t)
                yield from ready()
            if resampler is not None:
                for out in resampler.resample(None):
                    cutter.add(out)
        except av.FFmpegError as exc:
            raise DataError(f"{info.path}: decoding failed at {reached:.1f} s ({_reason(exc)}); the file is damaged") from None
        while emitted < n_seg:
            if not frames[emitted]:
                raise DataError(f"{info.path}: no video frames after {reached:.1f} s although the file says it lasts "
                                f"{info.duration:.1f} s (truncated or damaged)")
            yield clip(emitted)
            emitted += 1


class _AudioCutter:
    """Cuts the resampled mono stream at clip boundaries, on the video's clock."""

    def __init__(self, offset: float, bounds: list[tuple[float, float]], rate: int, audio: dict):
        self.rate, self.audio = rate, audio
        self.ends = [int(round(b * rate)) for _, b in bounds]
        self.pos = max(0, int(round(offset * rate)))  # audio that starts after the video: leading silence
        self.skip = max(0, int(round(-offset * rate)))  # audio that starts before the video: dropped
        if self.pos:
            self._put(np.zeros(self.pos, np.int16), 0)

    @property
    def t(self) -> float:
        return self.pos / self.rate

    def add(self, frame) -> None:
        pcm = frame.to_ndarray().reshape(-1)
        if self.skip:
            cut = min(self.skip, len(pcm))
            pcm, self.skip = pcm[cut:], self.skip - cut
        self._put(pcm, self.pos)
        self.pos += len(pcm)

    def _put(self, pcm: np.ndarray, start: int) -> None:
        end = start + len(pcm)
        for i in range(bisect.bisect_right(self.ends, start), len(self.ends)):
            stop = self.ends[i]
            lo = self.ends[i - 1] if i else 0
            a, b = max(start, lo), min(end, stop)
            if b > a and i in self.audio:  # clips already handed out take no late samples
                self.audio[i].append(pcm[a - start: b - start])
            if stop >= end:
                break

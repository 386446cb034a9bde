"""Synthetic videos made with PyAV for the video tests (e2e/video, e2e/ray): generated frames whose red channel
encodes the time, and a 440 Hz sine-wave audio track."""

from __future__ import annotations

import pytest

from memora_graph.testing.synthetic import make_synthetic_video

SHORT_SECONDS = 23.0  # three clips: 0-10, 10-20, 20-23 s
TONE_HZ = 440.0


@pytest.fixture(scope="session")
def short_video(tmp_path_factory):
    path = tmp_path_factory.mktemp("video") / "kitchen.mp4"
    return make_synthetic_video(path, SHORT_SECONDS, width=160, height=120, fps=10, tone_hz=TONE_HZ)


@pytest.fixture(scope="session")
def hd_video(tmp_path_factory):
    path = tmp_path_factory.mktemp("video") / "hd.mp4"
    return make_synthetic_video(path, 4.0, width=1280, height=720, fps=25, audio=False, preset="ultrafast")

"""`memora build --video DIR --executor ray` on a local Ray instance with 2 CPUs (`pytest -m ray`): one
task per participant folder, each talking to its own model server of a `--base-url` list (real HTTP
on 127.0.0.1, only the model's words scripted), gives the bank a local build gives."""

from __future__ import annotations

import shutil

import pytest
from click.testing import CliRunner
from memora_graph.testing.scripted_server import ScriptedServer, Turn

from memora_graph.bank import Bank
from memora_graph.cli import main

from e2e.video.test_video_build import CLIP0, CLIP1, CLIP2, EDIT0, EDIT1, EDIT2, USAGE

pytestmark = pytest.mark.ray


def _script():
    return [Turn(content=c, usage=USAGE) for c in (CLIP0, CLIP1, CLIP2)] + [Turn(content=c) for c in (EDIT0, EDIT1, EDIT2)]


def _args(bank, video, url, *extra):
    return ["build", str(bank), "--video", str(video), "--backend", "openai", "--base-url", url,
            "--perception-model", "qwen-vl", "--consolidation", "deterministic", "--quiet", *extra]


def test_video_builds_spread_over_servers_as_ray_tasks(ray_local, tmp_path, short_video):
    videos = tmp_path / "videos"
    for p in ("P01", "P02"):
        (videos / p).mkdir(parents=True)
        shutil.copy(short_video, videos / p / "kitchen.mp4")
    runner = CliRunner()
    with ScriptedServer(_script()) as local_server:
        local = runner.invoke(main, _args(tmp_path / "local", videos / "P01", local_server.base_url,
                                          "--participant", "P01"))
    assert local.exit_code == 0, local.output
    with ScriptedServer(_script()) as one, ScriptedServer(_script()) as two:
        r = runner.invoke(main, _args(tmp_path / "ray", videos, f"{one.base_url},{two.base_url}", "--executor", "ray"))
        assert r.exit_code == 0, r.output
        assert len(one.requests) == 6 and len(two.requests) == 6  # P01's task on the first server, P02's on the second
    assert "2 participant(s) built from video as Ray tasks" in r.output
    got, want = Bank(tmp_path / "ray").manifest(), Bank(tmp_path / "local").manifest()
    assert sorted(got["participants"]) == ["P01", "P02"] and "writing" not in got
    assert got["participants"]["P01"]["counts"] == want["participants"]["P01"]["counts"]
    assert got["participants"]["P01"]["videos"] == want["participants"]["P01"]["videos"] == ["kitchen"]
    assert got["participants"]["P02"]["counts"]["segments"] == want["participants"]["P01"]["counts"]["segments"]
    assert runner.invoke(main, ["verify", str(tmp_path / "ray")]).exit_code == 0

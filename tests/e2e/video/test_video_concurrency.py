"""`memora build --video --concurrency N`: perception of different videos is in flight together
(each video's clips in order), against a real HTTP server on 127.0.0.1 whose model words are a
function of the request (memora_graph/testing/responders.py: video); the bank is the one a
one-call-at-a-time build writes."""

from __future__ import annotations

import shutil

from support.scripted_server import ScriptedServer

from memora_graph.bank import Bank
from memora_graph.pipeline import build_from_video
from memora_graph.store import Store
from memora_graph.testing.responders import video


def _calls(bank, participant):
    with Store(Bank(bank).db_path(participant)) as store:
        return store.query("MATCH (c:ModelCall) WHERE c.participant = $p RETURN c.video AS video, c.turn AS turn, "
                           "c.role AS role, c.prompt_hash AS h, c.ok AS ok ORDER BY video, turn, role, h",
                           {"p": participant}).rows()


def test_two_videos_perceived_together_build_the_same_bank(short_video, tmp_path):
    videos = tmp_path / "videos"
    videos.mkdir()
    for name in ("P03_901.mp4", "P03_902.mp4"):
        shutil.copy(short_video, videos / name)
    results = {}
    for c in (1, 2):
        with ScriptedServer(responder=video, latency_s=0.2) as server:
            res = build_from_video(tmp_path / f"bank{c}", videos, "P03", backend="openai", base_url=server.base_url,
                                   perception_model="m", consolidation="deterministic",
                                   backend_options={"timeout_s": 30}, concurrency=c)
            stats = server.stats()
        results[c] = (res.counts, [v["segments"] for v in res.videos], _calls(tmp_path / f"bank{c}", "P03"), stats)
    assert results[1][3]["inflight_max"] == 1 and results[2][3]["inflight_max"] == 2
    assert results[1][1] == results[2][1] == [3, 3]
    assert results[1][0] == results[2][0]
    assert results[1][2] == results[2][2] and len(results[1][2]) == 12  # 6 perception + 6 editor calls

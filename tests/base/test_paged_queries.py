"""Named queries that could return a whole long memory return one video at a time (issue 36: every
named query the explorer and the server offer is bounded by what it returns). The pages, one per
video of `videos`, hold every record once, each page in time order."""

from __future__ import annotations

from memora_graph.bank import Bank


def test_baseline_records_come_a_video_at_a_time_and_together_are_every_record(small_bank):
    bank, _ = small_bank
    counts = Bank(bank).manifest()["participants"]["P37"]["counts"]
    with Bank(bank).open("P37") as store:
        videos = [r["video"] for r in store.rows("videos", participant="P37")]
        assert len(videos) > 1
        events = {v: store.rows("baseline_state_events", participant="P37", video=v) for v in videos}
        segments = {v: store.rows("baseline_segments", participant="P37", video=v) for v in videos}
        assert store.rows("baseline_segments", participant="P37", video="no-such-video") == []
        other = store.rows("baseline_segments", participant="P09", video=videos[0])
    assert other == [], "another participant's name reads nothing of P37's videos"
    every = [r["id"] for page in events.values() for r in page]
    assert len(every) == len(set(every)) == counts["state_events"]
    assert sum(len(p) for p in segments.values()) == counts["segments"]
    for v in videos:
        assert {r["video"] for r in events[v]} <= {v} and {r["video"] for r in segments[v]} <= {v}
        assert [r["t"] for r in events[v]] == sorted(r["t"] for r in events[v])
        assert [r["turn"] for r in segments[v]] == sorted(r["turn"] for r in segments[v])


def test_inferred_evidence_reads_one_record_by_id(small_bank):
    bank, _ = small_bank
    with Bank(bank).open("P37") as store:
        every = store.rows("_explore_evidence", participant="P37")
        assert every, "the small bank holds routines and preferences"
        for r in every[:: max(1, len(every) // 10)]:
            assert store.rows("inferred_evidence", participant="P37", id=r["id"]) == [r]
        assert store.rows("inferred_evidence", participant="P09", id=every[0]["id"]) == []
        assert store.rows("inferred_evidence", participant="P37", id="P37:routine:none") == []

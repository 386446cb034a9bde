"""A hand-built one-video memory for the retrieval tools (real Kùzu, real MiniLM embeddings)."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from memora_graph.store import Store

P = "P01"
VIDEO = "P01_101"

# (entity kind, t, state, location, zone, held_by, relative_to, relation, action)
HISTORY = [
    ("spoon", 2.0, "held", "counter_area", "", "hand", "", "", "take"),
    ("spoon", 3.0, "placed", "counter_area", "worktop", "", "top", "ON_TOP_OF", "put"),
    ("mug", 5.0, "held", "counter_area", "", "hand", "", "", "take"),
    ("kettle", 12.0, "on", "stove_area", "hob", "", "", "", "turn-on"),
    ("mug", 25.0, "placed", "sink_area", "sink", "", "sink", "INSIDE", "put"),
    ("kettle", 40.0, "off", "stove_area", "hob", "", "", "", "turn-off"),
    ("mug", 70.0, "washed", "sink_area", "sink", "hand", "", "", "wash"),
    ("sponge", 80.0, "held", "sink_area", "", "hand", "", "", "take"),
]
SUMMARIES = [
    "pick up spoon; put spoon on top", "boil the kettle", "put mug in sink", "put mug in sink.",
    "turn off kettle", "no narrated action", "no narrated action", "wash the mug in the sink",
    "pick up sponge", "no narrated action",
]


def _emb(vectors: np.ndarray) -> pl.Series:
    return pl.Series("emb", np.asarray(vectors, dtype=np.float32), dtype=pl.Array(pl.Float32, vectors.shape[1]))


def build_hand_store(path, embedder) -> Store:
    """One participant, one 100 s video, ten segments and the state history above."""
    s = Store(path, read_only=False)
    s.apply_schema()
    seg_ids = [f"{VIDEO}#t{i:04d}" for i in range(10)]
    with s.transaction():
        s.copy("Participant", pl.DataFrame({"id": [P], "participant": [P]}))
        s.copy("Video", pl.DataFrame({"id": [VIDEO], "participant": [P], "duration": [100.0], "n_turns": [10],
                                      "n_actions": [len(HISTORY)], "mode": ["edited"], "built_at": [None],
                                      "build_seconds": [0.0]}, schema_overrides={"built_at": pl.Datetime}))
        s.copy("Segment", pl.DataFrame({
            "id": seg_ids, "participant": P, "video": VIDEO, "turn": list(range(10)),
            "t_start": [10.0 * i for i in range(10)], "t_end": [10.0 * i + 10 for i in range(10)],
            "summary": SUMMARIES, "narrative": SUMMARIES, "action_breakdown": "[]", "working_summary": "",
            "location": ["counter_area", "stove_area", "sink_area", "sink_area", "stove_area", "sink_area",
                         "sink_area", "sink_area", "sink_area", "sink_area"],
            "n_actions": 1, "n_objects": 1,
        }).with_columns(_emb(embedder.encode(SUMMARIES))))
        s.copy("HAS_SEGMENT", pl.DataFrame({"from": VIDEO, "to": seg_ids}))  # as a build links them (a video's rows are read from it)
        kinds = sorted({h[0] for h in HISTORY})
        last = {k: max(h[1] for h in HISTORY if h[0] == k) for k in kinds}
        first = {k: min(h[1] for h in HISTORY if h[0] == k) for k in kinds}
        s.copy("Entity", pl.DataFrame({
            "id": [f"{P}:{k}" for k in kinds], "participant": P, "object_id": kinds, "kind": kinds, "name": kinds,
            "category": "crockery", "color": "", "material": "", "size": "", "is_fixture": False, "status": "active",
            "merged_into": "", "state": "", "location": "", "held_by": "",
            "first_seen": [first[k] for k in kinds], "first_video": VIDEO, "first_turn": [int(first[k] // 10) for k in kinds],
            "last_seen": [last[k] for k in kinds], "last_video": VIDEO, "last_turn": [int(last[k] // 10) for k in kinds],
            "n_observations": [sum(h[0] == k for h in HISTORY) for k in kinds],
        }).with_columns(_emb(embedder.encode(kinds))))
        ev = pl.DataFrame([{
            "id": f"{P}:{k}@{n}", "participant": P, "entity": f"{P}:{k}", "video": VIDEO, "turn": int(t // 10), "t": t,
            "ord": n, "state": state, "location": loc, "prev_state": "", "prev_location": "", "zone": zone,
            "held_by": held, "relative_to": rel_to, "relation": rel, "action": action, "narration": f"{action} {k}",
            "op": "UPDATE",
        } for n, (k, t, state, loc, zone, held, rel_to, rel, action) in enumerate(HISTORY, 1)])
        s.copy("StateEvent", ev)
        s.copy("HAS_STATE", ev.select(pl.col("entity").alias("from"), pl.col("id").alias("to"), "ord"))
        s.copy("OBSERVED_IN", ev.select(pl.col("id").alias("from"),
                                        (pl.lit(f"{VIDEO}#t") + (pl.col("turn").cast(pl.String).str.zfill(4))).alias("to")))
    s.ensure_indexes()
    return s


@pytest.fixture()
def hand_store(tmp_path, embedder):
    s = build_hand_store(tmp_path / "P01.kuzu", embedder)
    yield s
    s.close()

"""Build a participant's memory: perceive each video, Edit(M, z) turn by turn, write per video.

Each video is written in one Kùzu transaction together with its Video node, which is the
checkpoint: a killed build loses at most the video in progress, and a re-run skips the
videos already there, reloading the registry from the graph so nothing is duplicated.
"""

from __future__ import annotations

import json
import os
import pickle
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import polars as pl

from memora_graph.bank import Bank
from memora_graph.embed import CachedEmbedder
from memora_graph.form.editor import DeterministicPolicy, EditPolicy, EntityEditor, EntityState, RawPolicy, identity_text
from memora_graph.form.environment import PlaceMemory, PlaceState, place_id
from memora_graph.llm.backends import CallLog, CallRecord, ModelReplyError
from memora_graph.perceive.annotations import ClassTables
from memora_graph.perceive.narration import perceive_video
from memora_graph.records import LayeredSegment
from memora_graph.store import Store

MODES = ("edited", "raw")


@dataclass
class Timings:
    perception: float = 0.0
    editor: float = 0.0
    embedding: float = 0.0
    graph: float = 0.0

    def add(self, other: Timings) -> None:
        for k in self.__dataclass_fields__:
            setattr(self, k, getattr(self, k) + getattr(other, k))

    @property
    def total(self) -> float:
        return self.perception + self.editor + self.embedding + self.graph


@dataclass
class ParticipantBuild:
    participant: str
    videos_built: int = 0
    videos_skipped: int = 0
    segments: int = 0
    timings: Timings = field(default_factory=Timings)
    counts: dict = field(default_factory=dict)
    decisions: dict = field(default_factory=dict)

    @property
    def compression(self) -> float:
        active = self.counts.get("entities") or 0
        return (self.counts.get("state_events", 0) / active) if active else 0.0


def _emb_series(vectors: list[np.ndarray], dim: int) -> pl.Series:
    arr = np.asarray(vectors, dtype=np.float32).reshape(len(vectors), dim)
    return pl.Series("emb", arr, dtype=pl.Array(pl.Float32, dim))


def _entity_row(e: EntityState) -> dict:
    return {k: getattr(e, k) for k in (
        "id", "participant", "object_id", "kind", "name", "category", "color", "material", "size", "is_fixture",
        "status", "merged_into", "state", "location", "held_by", "first_seen", "first_video", "first_turn",
        "last_seen", "last_video", "last_turn", "n_observations")}


class ParticipantBuilder:
    """Owns one participant's database, editor and environment memory for the length of a build.

    Each finished video is checkpointed to `BANK/.staging/<participant>/` (its records plus a
    snapshot of the registry), written atomically; `finish()` loads every staged video into
    Kùzu in one transaction. Kùzu's commit cost grows with the size of the relationship tables,
    so one bulk load per participant is far faster than one transaction per video, while a
    killed build still loses at most the video in progress.
    """

    def __init__(self, bank: Bank, participant: str, embedder: CachedEmbedder, mode: str = "edited",
                 policy: EditPolicy | None = None, prompt_budget: int = 50, call_log: CallLog | None = None):
        """`call_log`: the model calls of this build; each video stages the calls tagged with it."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}")
        self.bank, self.participant, self.embedder, self.mode = bank, participant, embedder, mode
        self.call_log = call_log
        self.store = Store(bank.db_path(participant), read_only=False, bulk=True)
        self.store.apply_schema()
        self.staging = bank.path / ".staging" / participant
        self.in_db = set(self.store.run("videos", participant=participant)["video"].to_list())
        entities = [self._entity_from_row(r) for r in self.store.rows("_registry_entities", participant=participant)]
        places = [PlaceState(**r) for r in self.store.rows("_registry_places", participant=participant)]
        self.db_entities = {e.id: (e.status, e.location) for e in entities}
        self.db_entity_rows = {e.id: _entity_row(e) for e in entities}
        self.db_places = {p.location_id: p.turn_count for p in places}
        next_ord = int(self.store.run("_max_state_ord", participant=participant)["max_ord"][0] or 0)
        self.editor = EntityEditor(participant, policy or (RawPolicy() if mode == "raw" else DeterministicPolicy()),
                                   embed=self._embed_one, prompt_budget=prompt_budget, entities=entities, next_ord=next_ord)
        self.places = PlaceMemory(participant, places)
        self._op_seq = int(self.store.run("_edit_op_count", participant=participant)["n"][0] or 0)
        self.staged: list[Path] = []
        self._restore_staged()
        self.done = self.in_db | {f.name.split("_", 1)[1].removesuffix(".pkl") for f in self.staged}

    @staticmethod
    def _entity_from_row(r: dict) -> EntityState:
        emb = r.pop("emb")
        e = EntityState(**{k: (v if v is not None else "") for k, v in r.items()})
        e.emb = np.asarray(emb, dtype=np.float32) if emb is not None else None
        return e

    def _embed_one(self, text: str) -> np.ndarray:
        return self.embedder.encode([text])[0]

    def close(self) -> None:
        self.store.close()

    # -- checkpoints -------------------------------------------------------------------
    def _restore_staged(self) -> None:
        if not self.staging.is_dir():
            return
        for f in sorted(self.staging.glob("*.pkl")):
            video = f.name.split("_", 1)[1].removesuffix(".pkl")
            if video in self.in_db:  # loaded by an earlier run that died before cleaning up
                f.unlink()
            else:
                self.staged.append(f)
        for f in self.staging.glob("*.tmp"):
            f.unlink()  # a checkpoint that was being written when the build died
        if self.staged:
            with open(self.staged[-1], "rb") as fh:
                snap = pickle.load(fh)["snapshot"]
            self.editor.entities = snap["entities"]
            self.editor._ord, self.editor._raw_seq = snap["ord"], snap["raw_seq"]
            self.places.places = snap["places"]
            self._op_seq = snap["op_seq"]

    def _stage(self, video_id: str, frames: dict) -> None:
        self.staging.mkdir(parents=True, exist_ok=True)
        path = self.staging / f"{len(self.staged) + len(self.in_db):04d}_{video_id}.pkl"
        snapshot = {"entities": self.editor.entities, "places": self.places.places, "ord": self.editor._ord,
                    "raw_seq": self.editor._raw_seq, "op_seq": self._op_seq}
        tmp = path.with_suffix(".tmp")
        with open(tmp, "wb") as fh:
            pickle.dump({"frames": frames, "snapshot": snapshot}, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
        self.staged.append(path)

    # ---------------------------------------------------------------------------------
    def build_video(self, video_id: str, actions: list[dict], duration: float, classes: ClassTables) -> tuple[Timings, int]:
        t = Timings()
        t0 = time.perf_counter()
        segments = list(perceive_video(self.participant, video_id, actions, duration, classes))
        t.perception = time.perf_counter() - t0
        self._edit_and_stage(video_id, segments, duration, len(actions), t)
        return t, len(segments)

    def build_segments(self, video_id: str, segments: list[LayeredSegment], duration: float,
                       n_turns: int | None = None) -> tuple[Timings, list[int]]:
        """Edit and stage segments perceived elsewhere (video through a VLM). `n_turns` counts
        the clips including those perception failed on. A segment whose editor call fails is
        not written at all (no half-written segment); the model calls of the video, failed ones
        included, are staged with it. Returns the timings and the turn ids that were dropped."""
        t = Timings()
        n_actions = sum(len(s.activity.action_breakdown) for s in segments)  # the perceived actions
        dropped = self._edit_and_stage(video_id, segments, duration, n_actions, t, n_turns=n_turns)
        return t, dropped

    def _edit_and_stage(self, video_id: str, segments: list[LayeredSegment], duration: float, n_actions: int,
                        t: Timings, n_turns: int | None = None) -> list[int]:
        emb0 = self.embedder.seconds
        seg_vecs = self.embedder.encode([s.activity.summary for s in segments])
        # Identity texts are embedded up front, so editor time below is editing, not encoding.
        self.embedder.encode(sorted({identity_text(o.name, o.category) for s in segments for o in s.objects}))
        t.embedding = self.embedder.seconds - emb0

        t0 = time.perf_counter()
        edits, in_place, spatial, kept, dropped = [], [], [], [], []
        for seg, vec in zip(segments, seg_vecs):
            try:
                result = self.editor.edit(seg)  # a policy decides before anything is applied
            except ModelReplyError:
                dropped.append(seg.turn_id)
                continue
            edits.append((seg, result))
            kept.append((seg, vec))
            ip, sp = self.places.merge(seg)
            in_place += ip
            spatial += sp
        t.editor = time.perf_counter() - t0
        segments, seg_vecs = [s for s, _ in kept], [v for _, v in kept]

        t0 = time.perf_counter()
        frames = self._frames(video_id, duration, n_actions, segments, seg_vecs, edits, in_place, spatial)
        if n_turns is not None:
            frames["Video"] = frames["Video"].with_columns(pl.lit(n_turns, dtype=pl.Int64).alias("n_turns"))
        if self.call_log is not None:
            frames["ModelCall"] = model_call_frame(self.participant, video_id, self.call_log.records)
        self._stage(video_id, frames)
        t.graph = time.perf_counter() - t0
        self.done.add(video_id)
        return dropped

    def _frames(self, video_id, duration, n_actions, segments: list[LayeredSegment], seg_vecs, edits, in_place, spatial) -> dict:
        p = self.participant
        seg_df = pl.DataFrame({
            "id": [s.segment_id for s in segments], "participant": p, "video": video_id,
            "turn": [s.turn_id for s in segments], "t_start": [s.t_start for s in segments],
            "t_end": [s.t_end for s in segments], "summary": [s.activity.summary for s in segments],
            "narrative": [s.activity.detailed_narrative for s in segments],
            "action_breakdown": [json.dumps([a.model_dump() for a in s.activity.action_breakdown]) for s in segments],
            "working_summary": [s.working_summary for s in segments],
            "location": [s.environment.location_id for s in segments],
            "n_actions": [len(s.activity.action_breakdown) for s in segments],
            "n_objects": [len(s.objects) for s in segments],
        }).with_columns(_emb_series(list(seg_vecs), self.embedder.dim))
        events, ops_rows, edited, merged = [], [], [], []
        for seg, res in edits:
            events += res.events
            for op, obs in res.ops:
                self._op_seq += 1
                oid = f"{p}:op{self._op_seq:07d}"
                ops_rows.append({"id": oid, "participant": p, "video": video_id, "turn": seg.turn_id,
                                 "t": round(seg.t_start + obs.t_rel, 3), "op": op.op, "entity": op.entity_id,
                                 "reason": op.reason, "changes": json.dumps(op.changes, sort_keys=True),
                                 "policy": self.editor.policy.name})
                edited.append({"from": oid, "to": op.entity_id})
                if op.merged_into:
                    merged.append({"from": op.entity_id, "to": op.merged_into, "video": video_id, "turn": seg.turn_id})
        ev = pl.DataFrame(events) if events else None
        return {
            "Video": pl.DataFrame({"id": [video_id], "participant": [p], "duration": [float(duration)],
                                   "n_turns": [len(segments)], "n_actions": [n_actions], "mode": [self.mode],
                                   "built_at": [datetime.now(timezone.utc).replace(tzinfo=None)], "build_seconds": [0.0]}),
            "HAS_VIDEO": pl.DataFrame({"from": [p], "to": [video_id]}),
            "Segment": seg_df,
            "HAS_SEGMENT": pl.DataFrame({"from": video_id, "to": seg_df["id"]}),
            "NEXT": pl.DataFrame({"from": seg_df["id"][:-1], "to": seg_df["id"][1:]}),
            "IN_PLACE": pl.DataFrame(in_place, schema={"from": pl.String, "to": pl.String, "op": pl.String,
                                                      "is_primary": pl.Boolean, "zones": pl.List(pl.String)}),
            "SPATIAL": pl.DataFrame(spatial) if spatial else None,
            "StateEvent": ev.drop("segment") if ev is not None else None,
            "HAS_STATE": ev.select(pl.col("entity").alias("from"), pl.col("id").alias("to"), "ord") if ev is not None else None,
            "OBSERVED_IN": ev.select(pl.col("id").alias("from"), pl.col("segment").alias("to")) if ev is not None else None,
            "AT": ev.select(pl.col("id").alias("from"), (pl.lit(p + ":") + pl.col("location")).alias("to")) if ev is not None else None,
            "EditOp": pl.DataFrame(ops_rows) if ops_rows else None,
            "EDITED": pl.DataFrame(edited) if edited else None,
            "MERGED_INTO": pl.DataFrame(merged) if merged else None,
        }

    def finish(self) -> float:
        """Load every staged video into the graph in one transaction; returns seconds spent."""
        if not self.staged:
            return 0.0
        t0 = time.perf_counter()
        staged = []
        for f in self.staged:
            with open(f, "rb") as fh:
                staged.append(pickle.load(fh)["frames"])
        p, dim = self.participant, self.embedder.dim
        ents = self.editor.entities
        new_ents = [ents[i] for i in sorted(ents) if i not in self.db_entities]
        changed = [ents[i] for i in sorted(ents) if i in self.db_entities and _entity_row(ents[i]) != self.db_entity_rows[i]]
        relocated = [e.id for e in changed if (e.status, e.location) != self.db_entities[e.id]]
        located = [{"from": e.id, "to": place_id(p, e.location)} for e in new_ents if e.status == "active"]
        located += [{"from": i, "to": place_id(p, ents[i].location)} for i in relocated if ents[i].status == "active"]
        new_places = [pp for loc, pp in sorted(self.places.places.items()) if loc not in self.db_places]
        changed_places = [pp for loc, pp in sorted(self.places.places.items())
                          if loc in self.db_places and pp.turn_count != self.db_places[loc]]
        place_vecs = self.embedder.encode([pp.text() for pp in new_places + changed_places])
        with self.store.transaction():
            s = self.store
            if not s.run("_participant_exists", participant=p)["n"][0]:
                s.copy("Participant", pl.DataFrame({"id": [p], "participant": [p]}))
            for table in NODE_ORDER:
                frames = [st[table] for st in staged if st.get(table) is not None]
                if table == "Place" and new_places:
                    s.copy("Place", pl.DataFrame([_place_row(pp) for pp in new_places]).with_columns(
                        _emb_series(list(place_vecs[: len(new_places)]), dim)))
                elif table == "Entity" and new_ents:
                    s.copy("Entity", pl.DataFrame([_entity_row(e) for e in new_ents], schema=ENTITY_SCHEMA).with_columns(
                        _emb_series([e.emb if e.emb is not None else np.zeros(dim) for e in new_ents], dim)))
                elif frames:
                    s.copy(table, pl.concat(frames, how="vertical_relaxed"))
            if changed:
                s.run("_entity_update", participant=p, rows=[_entity_row(e) for e in changed])
            if changed_places:
                s.run("_place_update", participant=p, rows=[
                    {"id": pp.id, "zones": pp.zones, "features": pp.features, "last_seen": pp.last_seen,
                     "last_video": pp.last_video, "turn_count": pp.turn_count, "emb": v.tolist()}
                    for pp, v in zip(changed_places, place_vecs[len(new_places):])])
            if relocated:
                s.run("_located_at_clear", participant=p, ids=relocated)
            if located:
                s.copy("LOCATED_AT", pl.DataFrame(located))
            for table in REL_ORDER:
                frames = [st[table] for st in staged if st.get(table) is not None]
                if frames:
                    s.copy(table, pl.concat(frames, how="vertical_relaxed"))
        for f in self.staged:
            f.unlink()
        self.in_db |= self.done
        self.staged = []
        return time.perf_counter() - t0

    def counts(self) -> dict:
        return {k: int(v or 0) for k, v in self.store.run("store_counts", participant=self.participant).to_dicts()[0].items()}

    def decisions(self) -> dict:
        return {r["op"]: r["n"] for r in self.store.rows("decision_mix", participant=self.participant)}


NODE_ORDER = ("Video", "Segment", "Place", "Entity", "StateEvent", "EditOp", "ModelCall")
REL_ORDER = ("HAS_VIDEO", "HAS_SEGMENT", "NEXT", "IN_PLACE", "SPATIAL", "HAS_STATE", "OBSERVED_IN", "AT",
             "EDITED", "MERGED_INTO")
ENTITY_SCHEMA = {
    "id": pl.String, "participant": pl.String, "object_id": pl.String, "kind": pl.String, "name": pl.String,
    "category": pl.String, "color": pl.String, "material": pl.String, "size": pl.String, "is_fixture": pl.Boolean,
    "status": pl.String, "merged_into": pl.String, "state": pl.String, "location": pl.String, "held_by": pl.String,
    "first_seen": pl.Float64, "first_video": pl.String, "first_turn": pl.Int64, "last_seen": pl.Float64,
    "last_video": pl.String, "last_turn": pl.Int64, "n_observations": pl.Int64,
}


def model_call_frame(participant: str, video_id: str, records: list[CallRecord]) -> pl.DataFrame | None:
    """The ModelCall rows of one video: every call tagged with it, failed ones included."""
    mine = [r for r in records if r.tags.get("video") == video_id and r.tags.get("participant", participant) == participant]
    if not mine:
        return None
    return pl.DataFrame([{
        "id": f"{participant}:{video_id}:call{i:05d}", "participant": participant, "video": video_id,
        "turn": int(r.tags["turn"]) if r.tags.get("turn", "").lstrip("-").isdigit() else -1,
        "segment": r.tags.get("segment", ""), "role": r.role, "backend": r.backend, "model": r.model or "",
        "prompt_hash": r.prompt_hash, "prompt_version": r.tags.get("prompt", ""), "tokens_in": r.tokens_in,
        "tokens_out": r.tokens_out, "latency_s": r.latency_s, "retries": r.retries, "repairs": r.repairs,
        "ok": r.ok, "error": r.error or "",
        "started_at": datetime.fromisoformat(r.started_at).astimezone(timezone.utc).replace(tzinfo=None),
    } for i, r in enumerate(mine)], schema=MODEL_CALL_SCHEMA)


MODEL_CALL_SCHEMA = {
    "id": pl.String, "participant": pl.String, "video": pl.String, "turn": pl.Int64, "segment": pl.String,
    "role": pl.String, "backend": pl.String, "model": pl.String, "prompt_hash": pl.String,
    "prompt_version": pl.String, "tokens_in": pl.Int64, "tokens_out": pl.Int64, "latency_s": pl.Float64,
    "retries": pl.Int64, "repairs": pl.Int64, "ok": pl.Boolean, "error": pl.String, "started_at": pl.Datetime("us"),
}


def _place_row(pp: PlaceState) -> dict:
    return {"id": pp.id, "participant": pp.participant, "location_id": pp.location_id, "name": pp.name,
            "zones": pp.zones, "features": pp.features, "first_seen": pp.first_seen, "first_video": pp.first_video,
            "last_seen": pp.last_seen, "last_video": pp.last_video, "turn_count": pp.turn_count}


def build_participant(bank: Bank, participant: str, actions: pl.DataFrame, durations: dict[str, float],
                      classes: ClassTables, embedder: CachedEmbedder, mode: str = "edited",
                      policy: EditPolicy | None = None, on_video: Callable[[str, int], None] | None = None,
                      stop_after: int | None = None) -> ParticipantBuild:
    """Build (or resume) one participant. `on_video(video_id, n_segments)` reports progress;
    `stop_after` builds at most that many videos (used to simulate an interrupted build)."""
    out = ParticipantBuild(participant)
    builder = ParticipantBuilder(bank, participant, embedder, mode=mode, policy=policy)
    try:
        by_video: dict[str, list[dict]] = {}
        for row in actions.filter(pl.col("participant_id") == participant).iter_rows(named=True):
            by_video.setdefault(row["video_id"], []).append(row)
        for video_id in sorted(by_video):
            if video_id in builder.done:
                out.videos_skipped += 1
                if on_video:
                    on_video(video_id, 0)
                continue
            if stop_after is not None and out.videos_built >= stop_after:
                break
            timings, n = builder.build_video(video_id, by_video[video_id], durations.get(video_id, 0.0), classes)
            out.timings.add(timings)
            out.videos_built += 1
            out.segments += n
            if on_video:
                on_video(video_id, n)
        t0 = time.perf_counter()
        builder.finish()
        out.counts = builder.counts()
        out.decisions = builder.decisions()
        bank.record_participant(participant, sorted(builder.done), out.counts)
        out.timings.graph += time.perf_counter() - t0
    finally:
        builder.close()
    return out

"""Build a participant's memory: perceive each video, Edit(M, z) turn by turn, write per video.

Each video is written in one Kùzu transaction together with its Video node, which is the
checkpoint: a killed build loses at most the video in progress, and a re-run skips the
videos already there, reloading the registry from the graph so nothing is duplicated.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.parquet as pq

from memora_graph import schema
from memora_graph.bank import Bank
from memora_graph.embed import CachedEmbedder
from memora_graph.errors import DiskFullError
from memora_graph.form.editor import (
    EditPolicy, EntityEditor, EntityState, editor_policy_names, get_editor_policy, identity_text,
)
from memora_graph.form.environment import PlaceMemory, PlaceState, place_id
from memora_graph.form.staging import StagedVideo, Staging
from memora_graph.llm.backends import CallLog, CallRecord, ModelReplyError
from memora_graph.perceive.annotations import ClassTables
from memora_graph.perceive.narration import perceive_video
from memora_graph.records import LayeredSegment
from memora_graph.store import Store, disk_full, disk_full_message

MODES = tuple(editor_policy_names())  # "edited", "raw"


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


def load_entities(store: Store, participant: str) -> list[EntityState]:
    """Every entity of `participant` as the editor holds it, in id order: read as columns, the
    embeddings as one float32 array (each entity's `emb` a row of it; None where the row has
    none), a column left empty (NULL) read as "" as before. Whole nodes row by row cost ~1.4 CPU-s
    at 1,000 h (23,289 entities), the columns ~0.3."""
    frame = store.fetch_frame("_registry_entities", participant=participant)
    names = schema.columns("Entity", emb=False)
    if frame.columns != [*names, "emb"]:
        raise RuntimeError(f"_registry_entities returns {frame.columns}, not the Entity columns {[*names, 'emb']}")
    if not frame.height:
        return []
    frame = frame.sort("id")
    has = frame["emb"].is_not_null().to_numpy()
    rows = iter(frame["emb"].filter(frame["emb"].is_not_null()).to_numpy().astype(np.float32, copy=False)
                if has.any() else ())
    out = []
    for values, have in zip(frame.select(names).iter_rows(), has):
        e = EntityState(**{k: (v if v is not None else "") for k, v in zip(names, values)})
        e.emb = next(rows) if have else None
        out.append(e)
    return out


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


def entity_row(e: EntityState) -> dict:
    """An Entity row (schema columns, without the embedding) from the editor's record."""
    return {k: getattr(e, k) for k in schema.columns("Entity", emb=False)}


def place_row(pp: PlaceState) -> dict:
    return {k: getattr(pp, k) for k in schema.columns("Place", emb=False)}


class ParticipantBuilder:
    """One participant's editor and environment memory for the length of a build.

    The database is only read until `finish()`: the registry is loaded from it (read-only), and
    each finished video is staged in `BANK/.staging/<participant>/` (its rows plus the registry
    after it; see `form/staging.py`). `finish()` opens the database for writing and loads every
    staged video in one transaction. Kùzu's commit cost grows with the size of the relationship
    tables, so one bulk load per participant is far faster than one transaction per video, a
    killed build still loses at most the video in progress, and a build that fails before
    `finish()` has not touched the database.
    """

    def __init__(self, bank: Bank, participant: str, embedder: CachedEmbedder, mode: str = "edited",
                 policy: EditPolicy | None = None, prompt_budget: int = 50, call_log: CallLog | None = None):
        """`call_log`: the model calls of this build; each video stages the calls tagged with it."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}")
        self.bank, self.participant, self.embedder, self.mode = bank, participant, embedder, mode
        self.call_log = call_log
        self.store: Store | None = None
        self.db = bank.db_path(participant)
        self.staging = Staging(bank.path / ".staging" / participant)
        entities, places, next_ord, self._op_seq, self.in_db = [], [], 0, 0, set()
        bank.check_before_build(participant)
        self._resuming = bank.exists() and participant in bank.manifest().get("writing", {})
        if self._resuming:
            bank.mark_writing(participant, "build")  # resuming an unfinished write: this build finishes it
        if self.db.exists():
            with Store(self.db, read_only=True) as store:
                # a write interrupted before the schema's first file committed (a Ctrl-C, a kill)
                # left a file that holds nothing yet: the write applies the schema and loads all
                if not (self._resuming and "Video" not in store.tables()):
                    self.in_db = set(store.run("_videos_all", participant=participant)["video"].to_list())
                    entities = load_entities(store, participant)
                    places = [PlaceState(**_pick(r["place"], schema.columns("Place", emb=False)))
                              for r in store.fetch("_registry_places", participant=participant)]
                    next_ord = int(store.run("_max_state_ord", participant=participant)["max_ord"][0] or 0)
                    self._op_seq = int(store.run("_edit_op_count", participant=participant)["n"][0] or 0)
        self.db_entities = {e.id: (e.status, e.location) for e in entities}
        self.db_entity_rows = {e.id: entity_row(e) for e in entities}
        self.db_places = {p.location_id: p.turn_count for p in places}
        self.editor = EntityEditor(participant, policy or get_editor_policy(mode),
                                   embed=self._embed_one, prompt_budget=prompt_budget, entities=entities, next_ord=next_ord)
        self.places = PlaceMemory(participant, places)
        self.staged: list[StagedVideo] = []
        self.staged_now: list[StagedVideo] = []  # staged by this run (removed by `discard`)
        self.rebuilt: list[tuple[Path, str]] = []  # staged videos that failed their check
        self._restore_staged()
        self.done = self.in_db | {st.video for st in self.staged}

    def _embed_one(self, text: str) -> np.ndarray:
        return self.embedder.encode([text])[0]

    def close(self) -> None:
        if self.store is not None:
            self.store.close()
            self.store = None

    def discard(self) -> None:
        """Forget the videos this run staged (a failed build leaves the bank as it found it)."""
        self.staging.clear(self.staged_now)
        self.staged = [st for st in self.staged if st not in self.staged_now]
        self.staged_now = []

    # -- checkpoints -------------------------------------------------------------------
    def _restore_staged(self) -> None:
        self.staged, self.rebuilt = self.staging.load(skip=self.in_db)
        if not self.staged:
            return
        ents, places, counters = self.staged[-1].snapshot()
        emb = ents["emb"].to_numpy() if ents.height else np.zeros((0, self.embedder.dim), np.float32)
        entities = {}
        for row, vec, has in zip(ents.drop("emb", "has_emb").iter_rows(named=True), emb, ents["has_emb"]):
            e = EntityState(**row)
            e.emb = np.asarray(vec, dtype=np.float32) if has else None
            entities[e.id] = e
        self.editor.entities = entities
        self.editor._ord, self.editor._raw_seq = counters["ord"], counters["raw_seq"]
        self.places.places = {r["location_id"]: PlaceState(**r) for r in places.iter_rows(named=True)}
        self._op_seq = counters["op_seq"]

    def _stage(self, video_id: str, frames: dict) -> None:
        ents = list(self.editor.entities.values())
        dim = self.embedder.dim
        entity_frame = schema.frame("Entity", [entity_row(e) for e in ents]).with_columns(
            _emb_series([e.emb if e.emb is not None else np.zeros(dim, np.float32) for e in ents], dim),
            pl.Series("has_emb", [e.emb is not None for e in ents], dtype=pl.Boolean))
        place_frame = schema.frame("Place", [place_row(pp) for pp in self.places.places.values()])
        counters = {"ord": self.editor._ord, "raw_seq": self.editor._raw_seq, "op_seq": self._op_seq}
        try:
            st = self.staging.write(len(self.staged) + len(self.in_db), video_id, frames, entity_frame, place_frame,
                                    counters)
        except OSError as exc:
            if disk_full(exc, self.staging.root):
                raise DiskFullError(disk_full_message(self.staging.root)) from exc
            raise
        self.staged.append(st)
        self.staged_now.append(st)

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
            frames["ModelCall"] = model_call_frame(self.participant, self.call_log.records, f"{self.participant}:{video_id}",
                                                   video_id=video_id)
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
        p, dim = self.participant, self.embedder.dim
        ents = self.editor.entities
        new_ents = [ents[i] for i in sorted(ents) if i not in self.db_entities]
        changed = [ents[i] for i in sorted(ents) if i in self.db_entities and entity_row(ents[i]) != self.db_entity_rows[i]]
        relocated = [e.id for e in changed if (e.status, e.location) != self.db_entities[e.id]]
        located = [{"from": e.id, "to": place_id(p, e.location)} for e in new_ents if e.status == "active"]
        located += [{"from": i, "to": place_id(p, ents[i].location)} for i in relocated if ents[i].status == "active"]
        new_places = [pp for loc, pp in sorted(self.places.places.items()) if loc not in self.db_places]
        changed_places = [pp for loc, pp in sorted(self.places.places.items())
                          if loc in self.db_places and pp.turn_count != self.db_places[loc]]
        place_vecs = self.embedder.encode([pp.text() for pp in new_places + changed_places])
        self.bank.mark_writing(p, "build")  # until the bank records the database's integrity again
        try:
            self.store = Store(self.db, read_only=False, bulk=True)
        except BaseException:
            if self._resuming:
                self.bank.abandon_writing(p)  # still the earlier write's unfinished state
            else:
                self.bank.clear_writing(p)  # nothing was written
            raise
        self.store.apply_schema()
        with self.store.transaction():
            s = self.store
            if not s.run("_participant_exists", participant=p)["n"][0]:
                s.copy("Participant", pl.DataFrame({"id": [p], "participant": [p]}))
            for table in NODE_ORDER:
                frames = self._staged_frames(table)  # read lazily, a chunk of videos at a time
                if table == "Place" and new_places:
                    s.copy("Place", schema.frame("Place", [place_row(pp) for pp in new_places]).with_columns(
                        _emb_series(list(place_vecs[: len(new_places)]), dim)))
                elif table == "Entity" and new_ents:
                    s.copy("Entity", schema.frame("Entity", [entity_row(e) for e in new_ents]).with_columns(
                        _emb_series([e.emb if e.emb is not None else np.zeros(dim) for e in new_ents], dim)))
                else:
                    self._copy_chunks(table, frames)
            if changed:
                s.run("_entity_update", participant=p, rows=[entity_row(e) for e in changed])
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
                self._copy_chunks(table, self._staged_frames(table))
        self.store.close()  # checkpoint: the staged videos are in the database file now
        self.store = None
        self.staging.clear(self.staged)
        self.in_db |= self.done
        self.staged, self.staged_now = [], []
        return time.perf_counter() - t0

    def _staged_frames(self, table: str) -> Iterator[pl.DataFrame]:
        """The staged videos' rows of one table, each read from disk when the load reaches it."""
        return (f for st in self.staged if (f := st.frame(table)) is not None)

    def _copy_chunks(self, table: str, frames: Iterable[pl.DataFrame]) -> None:
        """COPY the videos' rows of one table in video order, through one Parquet file in the
        staging folder written a video at a time: Kùzu reads a file in batches, where COPYs of
        in-memory frames (50,000 rows each) held about four times the database in memory until
        the commit (the 1,000 h build's bulk load rose 5.5 GB this way, 1.5 GB from files). The
        rows and the one transaction are the same; the file is removed after."""
        folder = (self.staging.root / LOAD_DIR).absolute()  # COPY names it: a bank given as a relative path too
        path = folder / f"{table}.parquet"
        writer, first = None, None
        try:
            for f in frames:
                rows = schema.conform(table, f).to_arrow()
                if writer is None:
                    folder.mkdir(parents=True, exist_ok=True)
                    first = rows.schema
                    writer = pq.ParquetWriter(path, first)
                writer.write_table(rows.cast(first))
            if writer is None:
                return
            writer.close()
            writer = None
        except OSError as exc:
            if disk_full(exc, folder):
                raise DiskFullError(disk_full_message(folder)) from exc
            raise
        finally:
            if writer is not None:
                writer.close()
        try:
            self.store.copy_file(table, path)
        finally:
            path.unlink(missing_ok=True)
            try:
                folder.rmdir()
            except OSError:
                pass

    def _read(self, name: str) -> list[dict]:
        if self.store is not None:
            return self.store.rows(name, participant=self.participant)
        if not self.db.exists():
            return []
        with Store(self.db, read_only=True) as store:
            return store.rows(name, participant=self.participant)

    def counts(self) -> dict:
        rows = self._read("store_counts")
        return {k: int(v or 0) for k, v in rows[0].items()} if rows else {}

    def decisions(self) -> dict:
        return {r["op"]: r["n"] for r in self._read("decision_mix")}


# where the bulk load writes a table's Parquet file for its COPY (a ".tmp" folder: a build that
# finds one left by a killed load removes it, as it does a video left half-staged)
LOAD_DIR = ".load.tmp"
NODE_ORDER = ("Video", "Segment", "Place", "Entity", "StateEvent", "EditOp", "ModelCall")
REL_ORDER = ("HAS_VIDEO", "HAS_SEGMENT", "NEXT", "IN_PLACE", "SPATIAL", "HAS_STATE", "OBSERVED_IN", "AT",
             "EDITED", "MERGED_INTO")
def model_call_frame(participant: str, records: list[CallRecord], id_prefix: str,
                     video_id: str | None = None) -> pl.DataFrame | None:
    """ModelCall rows: every call (failed ones included) of `participant`, or only those tagged
    with `video_id`. Ids are `<id_prefix>:callNNNNN`. Calls that belong to no segment (the
    consolidation passes) have turn -1 and no segment. The one place these rows are made."""
    mine = [r for r in records if r.tags.get("participant", participant) == participant
            and (video_id is None or r.tags.get("video") == video_id)]
    if not mine:
        return None
    return schema.frame("ModelCall", [{
        "id": f"{id_prefix}:call{i:05d}", "participant": participant, "video": r.tags.get("video", ""),
        "turn": int(r.tags["turn"]) if str(r.tags.get("turn", "")).lstrip("-").isdigit() else -1,
        "segment": r.tags.get("segment", ""), "role": r.role, "backend": r.backend, "model": r.model or "",
        "prompt_hash": r.prompt_hash, "prompt_version": r.tags.get("prompt", ""), "tokens_in": r.tokens_in,
        "tokens_out": r.tokens_out, "latency_s": r.latency_s, "retries": r.retries, "repairs": r.repairs,
        "ok": r.ok, "error": r.error or "",
        "started_at": datetime.fromisoformat(r.started_at).astimezone(timezone.utc).replace(tzinfo=None),
    } for i, r in enumerate(mine)])


def _pick(row: dict, keys: list[str]) -> dict:
    return {k: row[k] for k in keys}


def annotation_fingerprints(actions: pl.DataFrame) -> dict[str, str]:
    """Per video, a sha256 of the annotation rows it is built from (every column but the line
    number, rows in narration order), so a later build can tell that a built video's
    annotations changed."""
    cols = [c for c in actions.columns if c != "row"]
    out = {}
    for video in sorted(actions["video_id"].unique().to_list()):
        rows = actions.filter(pl.col("video_id") == video).select(cols).sort("narration_id", "start_s")
        blob = json.dumps(rows.to_dicts(), sort_keys=True, default=str).encode()
        out[video] = hashlib.sha256(blob).hexdigest()[:20]
    return out


def build_participant(bank: Bank, participant: str, actions: pl.DataFrame, durations: dict[str, float],
                      classes: ClassTables, embedder: CachedEmbedder, mode: str = "edited",
                      policy: EditPolicy | None = None, on_video: Callable[[str, int], None] | None = None,
                      stop_after: int | None = None) -> ParticipantBuild:
    """Build (or resume) one participant. `on_video(video_id, n_segments)` reports progress;
    `stop_after` builds at most that many videos (used to simulate an interrupted build).
    A build that fails with an exception removes what it staged (a killed one keeps it, to
    resume); the database is only written by the final bulk load."""
    out = ParticipantBuild(participant)
    actions = actions.filter(pl.col("participant_id") == participant)
    with bank.participant_lock(participant):
        builder = ParticipantBuilder(bank, participant, embedder, mode=mode, policy=policy)
        try:
            # each video's rows as dicts only when it is built: a dict per row for every video at
            # once was ~2 GB at 1,000 hours (1.15 M rows), held for the whole build
            rows_of = dict(actions.select("video_id").with_row_index("_row").group_by("video_id", maintain_order=True)
                           .agg(pl.col("_row")).iter_rows())
            for video_id in sorted(rows_of):
                if video_id in builder.done:
                    out.videos_skipped += 1
                    if on_video:
                        on_video(video_id, 0)
                    continue
                if stop_after is not None and out.videos_built >= stop_after:
                    break
                video_actions = actions[rows_of[video_id]].to_dicts()
                timings, n = builder.build_video(video_id, video_actions, durations.get(video_id, 0.0), classes)
                out.timings.add(timings)
                out.videos_built += 1
                out.segments += n
                if on_video:
                    on_video(video_id, n)
            t0 = time.perf_counter()
            builder.finish()
            out.counts = builder.counts()
            out.decisions = builder.decisions()
            fingerprints = annotation_fingerprints(actions.filter(pl.col("video_id").is_in(sorted(builder.done))))
            bank.record_participant(participant, sorted(builder.done), out.counts, annotations=fingerprints)
            out.timings.graph += time.perf_counter() - t0
        except BaseException:
            if not isinstance(sys.exc_info()[1], KeyboardInterrupt):
                builder.discard()  # a failure; an interrupt keeps what was staged, to resume
            bank.abandon_writing(participant)
            raise
        finally:
            builder.close()
    return out

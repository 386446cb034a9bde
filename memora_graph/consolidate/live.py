"""Consolidation while living: incremental runs over a memory that grows one moment at a time.

The deterministic consolidator's per-video pass (storage preferences, organizational habits and
workflow patterns of one video) depends on that video's steps only. `IncrementalConsolidation`
keeps each video's results with a fingerprint of its steps (times, actions, the objects as the
editor resolves them now) and recomputes only the videos whose steps changed since the last run:
the videos that received new moments, or whose objects a later merge re-identified. What spans
videos (the recurring action sequences, the participant-level merge, the routine skills and
generated preferences of enrichment) is recomputed from the whole memory, as a batch run does,
so an incremental run writes exactly the records a batch run would (tests/serve/test_live_serve.py
compares them). The memory itself is still read whole (`load_memory`).

`BackgroundConsolidation` runs it inside `memora serve --writable --consolidate-every N`: after N
new segments a worker thread reads a committed snapshot through a second connection and infers
off the request path; only the write (one transaction replacing the inferred records) takes the
server's lock, and the readers' caches of inferred knowledge are swapped in the same critical
section: a call sees the old records or the new ones, never half.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from memora_graph.consolidate.memory import ParticipantMemory, MemoryStep, load_memory
from memora_graph.consolidate.processors import Processors, get_processors
from memora_graph.consolidate.records import VideoConsolidation
from memora_graph.consolidate.run import InferredKnowledge, infer, write_inferred
from memora_graph.errors import ConsolidationError

log = logging.getLogger("memora_graph.consolidate")
CACHE_FORMAT = 1


def video_fingerprint(steps: list[MemoryStep]) -> str:
    """What a video's per-video consolidation reads: every step's time, action, place and objects."""
    h = hashlib.sha256()
    for s in steps:
        h.update(repr((s.segment, s.t, s.verb, s.location, s.zone, s.destination, s.relation, s.narration,
                       [(o.kind, o.entity, o.category, o.is_fixture) for o in s.objects])).encode())
    return h.hexdigest()[:24]


@dataclass
class IncrementalConsolidation:
    """Per-video results of the deterministic consolidator, kept between runs (in memory, and
    in `cache_path` when given), so that a run recomputes only the videos that changed."""

    cache_path: Path | None = None
    videos: dict[str, tuple[str, dict]] = field(default_factory=dict)  # video -> (fingerprint, per-video records)
    recomputed: int = 0  # videos recomputed by the last run
    reused: int = 0

    def __post_init__(self) -> None:
        if self.cache_path is not None and self.cache_path.exists():
            try:
                data = json.loads(self.cache_path.read_text())
                if data.get("format") == CACHE_FORMAT:
                    self.videos = {v: (fp, rec) for v, (fp, rec) in data["videos"].items()}
            except (OSError, ValueError, KeyError, TypeError):
                self.videos = {}  # a damaged cache is recomputed, never trusted

    def save(self) -> None:
        if self.cache_path is None:
            return
        self.cache_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.cache_path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"format": CACHE_FORMAT, "videos": self.videos}))
        tmp.replace(self.cache_path)

    def infer(self, memory: ParticipantMemory, entity_ids: set[str], procs: Processors) -> InferredKnowledge:
        """`consolidate.run.infer`, with each unchanged video's per-video pass taken from the cache."""
        rules = procs.consolidation
        if procs.name != "deterministic" or not hasattr(rules, "video_storage"):
            raise ConsolidationError(f"incremental consolidation runs the deterministic processors, not {procs.name!r}")
        by_video = memory.steps_by_video()
        recurring = rules.recurring(memory)
        fresh: dict[str, tuple[str, dict]] = {}
        self.recomputed = self.reused = 0
        for video in memory.videos:
            steps = by_video.get(video, [])
            fp = video_fingerprint(steps)
            hit = self.videos.get(video)
            if hit is not None and hit[0] == fp:
                self.reused += 1
                fresh[video] = hit
            else:
                self.recomputed += 1
                part = VideoConsolidation(video=video, storage_preferences=rules.video_storage(video, steps),
                                          organizational_habits=rules.video_habits(video, steps),
                                          workflow_patterns=rules.video_workflows(video, steps))
                fresh[video] = (fp, part.model_dump(mode="json"))
        self.videos = fresh
        per_video = {v: VideoConsolidation.model_validate(rec).model_copy(update={
            "action_sequences": rules.video_sequences(v, by_video.get(v, []), recurring)}) for v, (_, rec) in fresh.items()}

        class _Cached:  # the per-video pass as `infer` calls it, answered from the results above
            name = rules.name

            def consolidate_video(self, memory, video):
                return per_video[video]

            def consolidate_participant(self, memory, parts):
                return rules.consolidate_participant(memory, parts)

        cached = Processors(name=procs.name, consolidation=_Cached(), enrichment=procs.enrichment)
        return infer(memory, entity_ids, cached)


def consolidate_incremental(read_store, write_store, participant: str, embedder, state: IncrementalConsolidation,
                            lock=None, on_written=None) -> InferredKnowledge:
    """Load the memory through `read_store`, infer (reusing `state`'s unchanged videos), and
    replace the inferred records through `write_store` in one transaction, holding `lock` (if
    given) for the write only; `on_written()` runs inside it."""
    procs = get_processors("deterministic")
    t0 = time.perf_counter()
    memory = load_memory(read_store, participant)
    entity_ids = {r["id"] for r in read_store.fetch("_consolidate_entity_ids", participant=participant)}
    t1 = time.perf_counter()
    knowledge = state.infer(memory, entity_ids, procs)
    t2 = time.perf_counter()
    if lock is not None:
        with lock:
            write_inferred(write_store, knowledge, embedder)
            if on_written is not None:
                on_written()
    else:
        write_inferred(write_store, knowledge, embedder)
        if on_written is not None:
            on_written()
    knowledge.seconds.update({"load": round(t1 - t0, 3), "infer": round(t2 - t1, 3),
                              "write": round(time.perf_counter() - t2, 3), "total": round(time.perf_counter() - t0, 3),
                              "videos_recomputed": state.recomputed, "videos_reused": state.reused})
    state.save()
    return knowledge


class BackgroundConsolidation:
    """Incremental consolidation of a live writer's participant after every `every` new segments,
    in a worker thread (see the module). `lock` is the one readers and the writer take."""

    def __init__(self, writer, every: int, lock, on_done=None):
        if every < 1:
            raise ValueError("consolidate every N segments: N must be at least 1")
        self.writer, self.every, self.lock, self.on_done = writer, every, lock, on_done
        self.state = IncrementalConsolidation(consolidation_cache(writer.bank.path, writer.participant))
        self.pending = 0
        self.runs: list[dict] = []  # seconds of each run (perf live reads them)
        self.error: BaseException | None = None
        self._wake = threading.Event()
        self._stop = False
        self._idle = threading.Event()
        self._idle.set()
        self._thread = threading.Thread(target=self._loop, name="memora-consolidate", daemon=True)
        self._thread.start()

    def added(self, n: int) -> None:
        self.pending += n
        if self.pending >= self.every:
            self._idle.clear()
            self._wake.set()

    def _loop(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            if self._stop:
                return
            n, self.pending = self.pending, 0
            try:
                self.run_once(n)
            except Exception as exc:  # noqa: BLE001 - the server keeps serving; the error is reported
                self.error = exc
                log.warning(f"{self.writer.participant}: background consolidation failed ({exc}); the previous "
                            "inferred knowledge is kept")
            self._idle.set()

    def run_once(self, n_new: int = 0) -> InferredKnowledge:
        reader = self.writer.store.reader()
        try:
            # the inferred records' vectors from the passage model a batch run uses (the writer's
            # own embedder may be MiniLM's ONNX export, form/live.py `live_embedder`)
            from memora_graph.embed import get_embedder

            embedder = get_embedder(self.writer.embedder.name)
            knowledge = consolidate_incremental(reader, self.writer.store, self.writer.participant,
                                                embedder, self.state, lock=self.lock,
                                                on_written=self.on_done)
        finally:
            reader.close()
        self.runs.append({"new_segments": n_new, **knowledge.seconds})
        return knowledge

    def wait(self, timeout: float | None = None) -> bool:
        """Until no run is pending or running (tests, benchmarks)."""
        return self._idle.wait(timeout)

    def stop(self) -> None:
        self._stop = True
        self._wake.set()
        self._thread.join(timeout=600)


def consolidation_cache(bank_path, participant: str) -> Path:
    return Path(bank_path) / ".cache" / f"consolidate-{participant}.json"


def consolidate_bank_incremental(bank, participants: list[str], embedder=None, on_done=None) -> list[dict]:
    """`memora consolidate --incremental`: each participant's inferred knowledge brought up to
    date, recomputing only the videos whose steps changed since the last run (the per-video
    results are kept in BANK/.cache/consolidate-PXX.json), recorded in the manifest like a batch
    run. A participant held by a live writer is refused (its server consolidates it)."""
    from memora_graph.bank import Bank
    from memora_graph.embed import get_embedder

    embedder = embedder or get_embedder(bank.manifest()["embed_model"])
    rows = []
    for p in participants:
        store = bank.open(p, read_only=False)
        try:
            store.apply_schema()
            state = IncrementalConsolidation(consolidation_cache(bank.path, p))
            knowledge = consolidate_incremental(store, store, p, embedder, state)
            counts = store.fetch("_inferred_counts", participant=p)[0]
        finally:
            store.close()  # records the integrity again

        def change(data: dict, p=p, counts=counts, knowledge=knowledge) -> None:
            entry = data["participants"][p]
            entry.setdefault("counts", {}).update({"routines": int(counts["routines"]),
                                                   "preferences": int(counts["preferences"])})
            entry["consolidated"] = True
            entry["inferred"] = {"processor": "deterministic", **knowledge.counts()}
            Bank.set_condition(data)

        bank.update_manifest(change)
        rows.append({"participant": p, "status": "consolidated", "routines": int(counts["routines"]),
                     "preferences": int(counts["preferences"]), "videos_recomputed": state.recomputed,
                     "videos_reused": state.reused, "seconds": knowledge.seconds["total"]})
        if on_done is not None:
            on_done(p)
    return rows

"""Consolidation while living: incremental runs whose cost follows what was added.

Every part of the deterministic consolidation is computed per video and then merged:
the per-video records (storage preferences, organizational habits, workflow patterns, action
sequences, with their evidence), the video's action n-grams (whether a sequence recurs across
videos), its episodes as the routine-skill merge reads them (goal, step tokens, canonical steps,
objects and entities) and its steps done with an instrument (generated preferences).
`IncrementalConsolidation` keeps these per-video folds between runs (in memory in the server,
and in `BANK/.cache/consolidate-PXX.json` for the CLI) and, per run:

1. finds the videos that changed, from what the bank records: each video's mark (its narrated
   observations: how many, first and last time; one aggregate over the state events) and the
   merged-duplicates map (an entity newly merged, or merged further, re-identifies the steps of
   every video that names it); a bank rebuilt since (its annotations or mode in the manifest)
   recomputes everything;
2. reads the steps of those videos only (`_consolidate_events_of` with `$videos`) and replaces
   their folds; a video that did not change but holds an n-gram that started or stopped
   recurring (the threshold is two videos) has its action sequences recounted (its steps read);
3. merges every video's folds as a batch run does (`RuleConsolidator.consolidate_participant`,
   `RuleEnricher.routine_skills_from` / `tool_preferences_from`, the same functions a batch run
   calls), a routine skill being recomputed only for goals whose episodes changed.

So an incremental run writes exactly the records a batch run would (tests/serve/
test_live_serve.py compares them at several points of a stream with merges) and reads from the
database only the changed videos' steps; the merge is over the small per-video folds.

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
import sys
import threading
import time
from collections import Counter
from pathlib import Path

from memora_graph.bank.derived import sha256_bytes
from memora_graph.consolidate.memory import Obj, StepReader, merged_map, resolve
from memora_graph.consolidate.records import Enrichment, VideoConsolidation
from memora_graph.consolidate.rules import EpisodeSummary, FoldIndex, RuleConsolidator, RuleEnricher, ToolUse
from memora_graph.consolidate.patterns import detect_all
from memora_graph.consolidate.run import InferredKnowledge, collect, write_inferred
from memora_graph.consolidate.task_records import CompactTask, Task
from memora_graph.consolidate.tasks import compact_video_tasks
from memora_graph.errors import BankError

log = logging.getLogger("memora_graph.consolidate")
CACHE_FORMAT = 4  # 4: folds keep their video's tasks
CACHE_RECORD = "consolidate"  # the kept folds' record in the manifest (bank/derived.py)
# The folds are kept on disk (JSON) only up to this size: reading a larger file back costs more
# time and memory than recomputing every video (format 2, records as JSON: 231 MB at 100 h took
# ~70 CPU-s and ~2 GB to read; format 3, compact: 41 MB at 100 h, 7.4 CPU-s). Above it a later
# `memora consolidate --incremental` recomputes every video, as a batch run; a server keeps its
# folds in memory whatever their size.
CACHE_MAX_BYTES = 64 << 20


class _VideoFold:
    """What one video contributes to the participant's inferred knowledge (see the module); its
    records are kept by the `FoldIndex`, compact."""

    __slots__ = ("mark", "raw", "segments", "ngrams", "episodes", "tool_uses", "tasks")

    def __init__(self, mark, raw, segments, ngrams, episodes, tool_uses, tasks=None):
        self.mark, self.raw, self.segments, self.ngrams = mark, raw, segments, ngrams
        self.episodes, self.tool_uses = episodes, tool_uses
        self.tasks = tasks or []  # the video's tasks (consolidate.tasks), compact: a video's own steps decide them

    def to_json(self, tables: dict) -> dict:
        """The fold as JSON; its n-grams and canonical steps as ids into `tables` (added to:
        "ngrams" and "steps", value -> id), which the file holds once."""
        ngrams, steps = tables.setdefault("ngrams", {}), tables.setdefault("steps", {})

        def step(t, a):
            return steps.setdefault((t, a.verb, a.noun, a.place, a.instrument), len(steps))

        return {"mark": list(self.mark), "raw": sorted(self.raw), "segments": sorted(self.segments),
                "ngrams": [ngrams.setdefault(t, len(ngrams)) for t in self.ngrams],
                "episodes": [[e.video, e.goal, e.head, e.cat, list(e.tokens), [step(t, a) for t, a in e.canon],
                              e.kinds, [[k, x, n] for (k, x), n in e.entities], e.t_start, e.t_end, e.segments]
                             for e in self.episodes],
                "tool_uses": [[u.verb, u.target, u.tool, u.video, u.segment, u.narration,
                               [[o.kind, o.entity, o.category, o.is_fixture] for o in u.objects]] for u in self.tool_uses],
                "tasks": [t.record().model_dump() for t in self.tasks]}

    @classmethod
    def from_json(cls, d: dict, tables: dict) -> _VideoFold:
        """`to_json`'s document (`tables`: its n-grams as tuples, its steps as (text, StepAction))."""
        ngrams, steps = tables["ngrams"], tables["steps"]
        episodes = [EpisodeSummary(video, goal, head, cat, tuple(tokens), [steps[i] for i in canon],
                                   kinds, [((k, x), n) for k, x, n in entities], t0, t1, segments)
                    for video, goal, head, cat, tokens, canon, kinds, entities, t0, t1, segments in d["episodes"]]
        tool_uses = [ToolUse(verb, target, tool, video, segment, narration, [Obj(*o) for o in objects])
                     for verb, target, tool, video, segment, narration, objects in d["tool_uses"]]
        return cls(tuple(d["mark"]), set(d["raw"]), set(d["segments"]), {ngrams[i] for i in d["ngrams"]},
                   episodes, tool_uses, [CompactTask.of(Task.model_validate(t)) for t in d.get("tasks", [])])


class _Recurring:
    """`RuleConsolidator.recurring` as a view of the kept n-gram counts (videos per n-gram)."""

    __slots__ = ("counts", "min_videos")

    def __init__(self, counts: Counter, min_videos: int):
        self.counts, self.min_videos = counts, min_videos

    def __contains__(self, tokens) -> bool:
        return self.counts.get(tokens, 0) >= self.min_videos


def bank_stamp(bank, participant: str) -> str:
    """What a rebuild of the participant changes in the manifest (its annotations, the bank's mode):
    kept folds are trusted only under the same stamp."""
    data = bank.manifest()
    entry = data.get("participants", {}).get(participant, {})
    return hashlib.sha256(json.dumps([data.get("mode"), entry.get("annotations")], sort_keys=True).encode()).hexdigest()[:16]


class IncrementalConsolidation:
    """Per-video folds of the deterministic consolidation, kept between runs (in memory, and in
    `cache_path` when given), so that a run reads and recomputes only the videos that changed."""

    def __init__(self, cache_path: Path | None = None, bank=None, participant: str | None = None):
        self.cache_path = cache_path
        # with a bank: the kept folds are read only when their sha256 is the one recorded in its
        # manifest when they were saved (bank/derived.py); others are recomputed, never trusted
        self.bank, self.participant = bank, participant
        self.rules, self.enricher = RuleConsolidator(), RuleEnricher()
        self.stamp: str | None = None
        self.merged: dict[str, str] = {}
        self.folds: dict[str, _VideoFold] = {}
        self.ngram_videos: Counter = Counter()  # n-gram -> videos it is seen in
        self.segment_ids: set[str] = set()  # the segments the folds were read from (what a record may cite)
        self.index = FoldIndex(self.rules)  # the per-video records merged, kept up to date video by video
        self.routines: dict[str, object] = {}  # goal -> RoutineSkill of the goal's current episodes
        self.unsaved = True  # folds changed since they were read from or written to `cache_path`
        self.saved: bool | None = None  # whether the last save() kept the folds on disk
        self.kept_bytes = 0  # their size as JSON at the last save()
        self.recomputed = 0  # videos read and recomputed by the last run
        self.reused = 0
        self.resequenced = 0  # unchanged videos whose action sequences were recounted
        if cache_path is not None and cache_path.exists():
            try:
                raw = cache_path.read_bytes()
                if bank is not None:
                    files = (bank.derived.get(participant, CACHE_RECORD) or {}).get("files")
                    if not isinstance(files, dict) or files.get(cache_path.name) != sha256_bytes(raw):
                        raise ValueError(f"{cache_path}: not as recorded in the bank's manifest")
                self._load(json.loads(raw))
                self.unsaved = False
            except (OSError, ValueError, KeyError, TypeError):
                self._reset()  # a damaged or unrecorded cache is recomputed, never trusted

    def _reset(self) -> None:
        self.unsaved = True
        self.stamp, self.merged, self.folds, self.ngram_videos, self.routines = None, {}, {}, Counter(), {}
        self.segment_ids = set()
        self.index = FoldIndex(self.rules)

    def _load(self, data: dict) -> None:
        from memora_graph.consolidate.records import RoutineSkill

        if data.get("format") != CACHE_FORMAT:
            return
        self.stamp, self.merged = data["stamp"], dict(data["merged"])
        tables = self.index.tables_from_json(data["tables"])
        share = self.index.share
        folds = {"ngrams": [share(tuple(sys.intern(x) for x in t)) for t in data["folds"].get("ngrams", [])],
                 "steps": [share(("step", t, *a), (t, self.index.step_action(tuple(a))))
                           for t, *a in data["folds"].get("steps", [])]}
        for v, (fold, rows) in data["videos"].items():
            f = self.folds[v] = _VideoFold.from_json(fold, folds)
            self._shared(f.episodes)
            self.ngram_videos.update(f.ngrams)
            self.segment_ids |= f.segments
            self.index.put(self.index.rows_from_json(rows, tables), v)
        self.routines = {g: RoutineSkill.model_validate(r) for g, r in data["routines"].items()}

    def save(self) -> None:
        if self.cache_path is None or (not self.unsaved and self.cache_path.exists()):
            return
        # one video at a time, counting, so that folds over the cap cost one video's JSON, not
        # every video's (at 100 h the whole document took ~1 GB to build only to be dropped)
        head = json.dumps({"format": CACHE_FORMAT, "stamp": self.stamp, "merged": self.merged,
                           "routines": {g: r.model_dump(mode="json") for g, r in self.routines.items()}})
        parts, size, firsts, folds = [head[:-1], ', "videos": {'], len(head) + 13, {}, {}
        for n, (v, f) in enumerate(self.folds.items()):
            part = ("" if n == 0 else ", ") + json.dumps(v) + ": " + json.dumps(
                [f.to_json(folds), self.index.rows_to_json(self.index.videos[v], firsts)])
            size += len(part)
            if size > CACHE_MAX_BYTES:  # not worth reading back (see CACHE_MAX_BYTES): none kept
                self.kept_bytes = size
                self.cache_path.unlink(missing_ok=True)
                self.saved = False
                return
            parts.append(part)
        parts.append('}, "tables": ' + json.dumps(self.index.tables_to_json(firsts)) + ', "folds": '
                     + json.dumps({k: list(v) for k, v in folds.items()}) + "}")
        text = "".join(parts)
        if len(text) > CACHE_MAX_BYTES:
            self.kept_bytes = len(text)
            self.cache_path.unlink(missing_ok=True)
            self.saved = False
            return
        self.kept_bytes = len(text)
        self.cache_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.cache_path.with_suffix(".tmp")
        tmp.write_text(text)
        tmp.replace(self.cache_path)
        self.unsaved = False
        self.saved = True
        if self.bank is not None:
            try:
                self.bank.derived.put(self.participant, CACHE_RECORD,
                                      {"files": {self.cache_path.name: sha256_bytes(text.encode())}})
            except (OSError, BankError):
                pass  # unrecorded: recomputed next time

    # -- a run -----------------------------------------------------------------------------
    def changed(self, marks: dict[str, tuple], merged: dict[str, str]) -> list[str]:
        """The videos whose steps may differ from their folds: new, or a moved mark, or naming an
        entity whose resolution through the merges changed."""
        moved = {e for e in self.merged.keys() | merged.keys() if resolve(self.merged, e) != resolve(merged, e)}
        out = []
        for video, mark in marks.items():
            f = self.folds.get(video)
            if f is None or f.mark != mark or (moved and not moved.isdisjoint(f.raw)):
                out.append(video)
        return out

    def infer(self, store, participant: str, entity_ids: set[str], stamp: str | None = None) -> InferredKnowledge:
        """Bring the folds up to date from `store` and merge them into the participant's records."""
        t0 = time.perf_counter()
        rules, enricher = self.rules, self.enricher
        if stamp is not None and self.stamp is not None and stamp != self.stamp:
            self._reset()  # rebuilt since: nothing kept is trusted
        if stamp and stamp != self.stamp:
            self.unsaved = True
        self.stamp = stamp or self.stamp
        marks = {r["video"]: (int(r["n"]), float(r["t_min"]), float(r["t_max"]))
                 for r in store.fetch("_consolidate_video_marks", participant=participant)}
        merged = merged_map(store, participant)
        dirty = self.changed(marks, merged)
        gone = [v for v in self.folds if v not in marks]
        touched_goals: set[str] = set()
        flipped: set[tuple] = set()  # n-grams that started or stopped recurring
        for video in [*dirty, *gone]:  # their old n-grams, episodes and segments leave the merge
            old = self.folds.pop(video, None)
            self.index.put(None, video)
            if old is not None:
                flipped |= self._count(old.ngrams, -1)
                touched_goals.update(e.goal for e in old.episodes)
                self.segment_ids -= old.segments
        reader = StepReader(merged)
        by_video = _by_video(reader.read(store, participant, {v: marks[v][0] for v in dirty}))
        t1 = time.perf_counter()
        fresh = {}
        for video in dirty:
            steps = by_video.get(video, [])
            ngrams = {self.index.share(tokens) for tokens, _ in rules._windows(steps)}  # equal n-grams: one tuple
            flipped |= self._count(ngrams, +1)
            fresh[video] = (steps, ngrams)
        recurring = _Recurring(self.ngram_videos, rules.min_videos)
        for video, (steps, ngrams) in fresh.items():
            records = VideoConsolidation(video=video, storage_preferences=rules.video_storage(video, steps),
                                         organizational_habits=rules.video_habits(video, steps),
                                         workflow_patterns=rules.video_workflows(video, steps),
                                         action_sequences=rules.video_sequences(video, steps, recurring))
            episodes = self._shared(enricher.video_episodes(steps))
            touched_goals.update(e.goal for e in episodes)
            self.folds[video] = _VideoFold(marks[video], reader.raw.get(video, set()), {s.segment for s in steps},
                                           ngrams, episodes, enricher.tool_uses(steps),
                                           compact_video_tasks(participant, steps) if steps else [])
            self.segment_ids |= self.folds[video].segments
            self.index.put(records, video)
        # an n-gram that started or stopped recurring changes the action sequences of the unchanged
        # videos that hold it: those are read again and recounted
        resequence = [v for v, f in self.folds.items() if v not in fresh and flipped and not flipped.isdisjoint(f.ngrams)]
        if resequence:
            more = _by_video(StepReader(merged).read(store, participant, {v: marks[v][0] for v in resequence}))
            for video in resequence:
                self.index.put_sequences(rules.video_sequences(video, more.get(video, []), recurring), video)
        if dirty or gone or resequence or merged != self.merged:
            self.unsaved = True
        self.merged = merged
        self.recomputed, self.reused, self.resequenced = len(dirty), len(self.folds) - len(dirty), len(resequence)
        t2 = time.perf_counter()

        videos = sorted(self.folds)
        consolidation = self.index.consolidation(participant)
        t3 = time.perf_counter()
        groups: dict[str, list[EpisodeSummary]] = {}
        for v in videos:
            for e in self.folds[v].episodes:
                groups.setdefault(e.goal, []).append(e)
        routines = {}
        for goal, eps in groups.items():  # a goal none of whose episodes changed keeps its routine skill
            if len(eps) < enricher.min_episodes:
                continue
            hit = self.routines.get(goal)
            routines[goal] = hit if hit is not None and goal not in touched_goals else enricher.routine_of(goal, eps)
        self.routines = routines
        skills = enricher.ranked_routines(routines.values())
        prefs = enricher.tool_preferences_from(u for v in videos for u in self.folds[v].tool_uses)
        enrichment = Enrichment(participant=participant, routine_skills=skills, generated_preferences=prefs)
        t4 = time.perf_counter()
        tasks = [t for v in videos for t in self.folds[v].tasks]
        out = collect(participant, self.segment_ids, entity_ids, consolidation, enrichment, rules.name,
                      tasks=tasks, patterns=detect_all(tasks))
        out.seconds = {"read": round(t1 - t0, 3), "folds": round(t2 - t1, 3), "consolidation": round(t3 - t2, 3),
                       "enrichment": round(t4 - t3, 3), "collect": round(time.perf_counter() - t4, 3)}
        return out

    def _shared(self, episodes: list[EpisodeSummary]) -> list[EpisodeSummary]:
        """`episodes` with their equal parts one object each (canonical steps, goals, objects): a
        canonical step as its own text and StepAction per episode was most of the ~70 MB the
        episodes of 100 h took."""
        share = self.index.share
        for e in episodes:
            e.goal, e.head, e.kinds = share(e.goal), share(e.head), [share(k) for k in e.kinds]
            e.canon = [share(("step", t, a.verb, a.noun, a.place, a.instrument), (t, a)) for t, a in e.canon]
            e.entities = [(share(ke), n) for ke, n in e.entities]
        return episodes

    def _count(self, ngrams, step: int) -> set[tuple]:
        """Add (+1) or remove (-1) one video's n-grams; returns those that crossed the threshold."""
        counts, k, flipped = self.ngram_videos, self.rules.min_videos, set()
        for t in ngrams:
            before = counts.get(t, 0)
            after = before + step
            if after:
                counts[t] = after
            else:
                del counts[t]
            if (before >= k) != (after >= k):
                flipped.add(t)
        return flipped


def _by_video(steps) -> dict[str, list]:
    out: dict[str, list] = {}
    for s in steps:
        out.setdefault(s.video, []).append(s)
    return out


def consolidate_incremental(read_store, write_store, participant: str, embedder, state: IncrementalConsolidation,
                            lock=None, on_written=None, stamp: str | None = None, save: bool = True) -> InferredKnowledge:
    """Bring `state`'s folds up to date through `read_store`, merge them, and replace the inferred
    records through `write_store` in one transaction, holding `lock` (if given) for the write
    only; `on_written()` runs inside it. `stamp` (`bank_stamp`) names the build the folds belong
    to (None: the caller vouches for it); `save` keeps the folds in the state's cache file."""
    t0 = time.perf_counter()
    entity_ids = {r["id"] for r in read_store.fetch("_consolidate_entity_ids", participant=participant)}
    try:
        knowledge = state.infer(read_store, participant, entity_ids, stamp)
    except BaseException:
        state._reset()  # folds half brought up to date are not trusted: the next run starts afresh
        raise
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
    knowledge.seconds.update({"infer": round(t2 - t0, 3), "write": round(time.perf_counter() - t2, 3),
                              "total": round(time.perf_counter() - t0, 3),
                              "videos_recomputed": state.recomputed, "videos_reused": state.reused,
                              "videos_resequenced": state.resequenced})
    if save:
        state.save()
    return knowledge


class BackgroundConsolidation:
    """Incremental consolidation of a live writer's participant after every `every` new segments,
    in a worker thread (see the module). `lock` is the one readers and the writer take."""

    def __init__(self, writer, every: int, lock, on_done=None):
        if every < 1:
            raise ValueError("consolidate every N segments: N must be at least 1")
        self.writer, self.every, self.lock, self.on_done = writer, every, lock, on_done
        self.state = IncrementalConsolidation(consolidation_cache(writer.bank.path, writer.participant),
                                              bank=writer.bank, participant=writer.participant)
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
                                                embedder, self.state, lock=self.lock, on_written=self.on_done,
                                                stamp=bank_stamp(self.writer.bank, self.writer.participant),
                                                save=False)
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
        if self.runs and self.error is None:
            self.state.save()  # for a later `memora consolidate --incremental` (while serving, writing
            # every video's folds would hold the interpreter for seconds at 100 h)


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
            state = IncrementalConsolidation(consolidation_cache(bank.path, p), bank=bank, participant=p)
            knowledge = consolidate_incremental(store, store, p, embedder, state, stamp=bank_stamp(bank, p))
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
                     "videos_reused": state.reused, "videos_resequenced": state.resequenced,
                     "folds_kept": state.saved is not False, "seconds": knowledge.seconds["total"]})
        if on_done is not None:
            on_done(p)
    return rows

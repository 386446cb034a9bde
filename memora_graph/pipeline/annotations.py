"""Build a memory bank from EPIC annotations: the library call behind `memora build`."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from memora_graph.bank import Bank, check_writable
from memora_graph.embed import ThreadGovernor, get_embedder
from memora_graph.errors import DataError, DiskFullError, StoreError
from memora_graph.form.build import ParticipantBuild, Timings
from memora_graph.perceive.annotations import load_annotations, load_class_tables, load_video_info
from memora_graph.pipeline.participant import build_one, BuiltParticipant
from memora_graph.pipeline.rollback import purge_trash, set_aside, undo_build
from memora_graph.pipeline.workers import build_parallel, auto_jobs
from memora_graph.store import disk_full, free_bytes


@dataclass
class BankBuild:
    participants: list[ParticipantBuild] = field(default_factory=list)
    timings: Timings = field(default_factory=Timings)  # the builder's own split, per video
    load_seconds: float = 0.0  # reading the annotations
    model_seconds: float = 0.0  # loading the embedding model (in each worker process, summed)
    wall_seconds: float = 0.0
    jobs: int = 1  # participants built side by side, one worker process each
    inferred: dict[str, dict] = field(default_factory=dict)  # participant -> routine / preference counts
    inferred_seconds: float = 0.0  # everything after each participant's bulk load (see `finish`)
    embedding_seconds: float = 0.0  # every text encoded: segments, identities, places, inferred knowledge
    texts_encoded: int = 0
    embed_threads: dict[int, int] = field(default_factory=dict)  # torch threads -> encode calls
    setup_seconds: float = 0.0  # per participant: opening its database, reloading its registry, checkpoint on close
    finish: dict[str, float] = field(default_factory=dict)  # the step after each bulk load, summed (finish_participant)
    unknown: object = None  # with `narrations`: the words no class covers (perceive/narrations.py Unknown)

    @property
    def segments(self) -> int:
        return sum(p.segments for p in self.participants)

    def add(self, r: BuiltParticipant) -> None:
        self.participants.append(r.build)
        self.timings.add(r.build.timings)
        self.setup_seconds += r.setup_seconds
        for k, v in r.finish.items():
            self.finish[k] = self.finish.get(k, 0.0) + v
        self.inferred[r.build.participant] = r.inferred
        self.inferred_seconds += r.inferred_seconds
        self.embedding_seconds += r.embedding_seconds
        self.texts_encoded += r.texts_encoded
        self.model_seconds += r.model_seconds
        for k, v in r.threads.items():
            self.embed_threads[k] = self.embed_threads.get(k, 0) + v

    def phases(self) -> dict[str, float]:
        """Where the time went, every phase once. They sum to `jobs * wall_seconds`: with one job
        to the wall time ('other' is what no phase timed: bank set-up, progress callbacks); with
        worker processes to their seconds, 'workers idle' being start-up and the end of the
        build, when fewer participants than workers are left."""
        t, f = self.timings, self.finish
        # the builder counts the place texts it encodes during its bulk load as graph time
        load_encoding = max(self.embedding_seconds - t.embedding - f.get("embedding", 0.0), 0.0)
        out = {
            "load annotations": self.load_seconds,
            "load embedding model": self.model_seconds,
            "perception": t.perception,
            "editor": t.editor,
            "embedding": self.embedding_seconds,
            "graph staging + bulk load": max(t.graph - load_encoding, 0.0),
            "database open / registry / checkpoint": self.setup_seconds + f.get("open", 0.0) + f.get("checkpoint", 0.0),
            "consolidation + enrichment": f.get("consolidation", 0.0),
            "indexes (--fts)": f.get("indexes", 0.0),
            "manifest": f.get("manifest", 0.0),
        }
        rest = max(self.jobs * self.wall_seconds - sum(out.values()), 0.0)
        out["other" if self.jobs == 1 else "workers idle"] = rest
        return out

    @property
    def busy_seconds(self) -> float:
        """The wall time with one job; the worker processes' working seconds with several."""
        return self.wall_seconds if self.jobs == 1 else sum(self.phases().values()) - self.phases()["workers idle"]

    @property
    def graph_seconds(self) -> float:
        """Graph work: everything except embedding and loading the embedding model."""
        return max(self.busy_seconds - self.embedding_seconds - self.model_seconds, 0.0)

    @property
    def graph_share(self) -> float:
        return self.graph_seconds / self.busy_seconds if self.busy_seconds else 0.0


# Database size of a built participant, measured on the bundled build with consolidation:
# P09 160 segments 20.2 MB, P37 278 -> 26.9 MB, P04 1187 -> 36.3 MB: Kùzu allocates ~18-20 MB up
# front, then ~15-20 kB per 10 s segment. While a participant loads, its staged videos, write-ahead
# log and shadow pages come on top (P04 peaked at 49.4 MB, 1.36x its final size).
NEW_DATABASE_BYTES = 20_000_000
BYTES_PER_SEGMENT = 20_000
PEAK_FACTOR = 1.4


def space_needed(plan: dict[str, list[str]], durations: dict[str, float], built: dict[str, set] | None = None) -> float:
    """Bytes a build is expected to need, from the 10 s segments of the videos not built yet
    (and a new database for each participant not in `built`)."""
    built = built or {}
    total = 0.0
    for p, videos in plan.items():
        segments = sum(max(1, math.ceil(durations.get(v, 0.0) / 10.0)) for v in videos if v not in built.get(p, set()))
        if segments:
            total += segments * BYTES_PER_SEGMENT + (NEW_DATABASE_BYTES if p not in built else 0)
    return total * PEAK_FACTOR


def check_space(bank: Bank, needed: float) -> None:
    free = free_bytes(bank.path)
    if free is not None and needed > free:
        raise DiskFullError(f"{bank.path}: no space left on device for this build (needed about {needed / 1e6:.0f} MB, "
                            f"{free / 1e6:.0f} MB free). Free some space, or build fewer participants at a time.")


def changed_annotations(bank: Bank, df, participants: list[str]) -> dict[str, list[str]]:
    """Built videos whose annotation rows differ from those they were built from, per participant."""
    if not bank.exists():
        return {}
    from memora_graph.form.build import annotation_fingerprints

    entries = bank.manifest()["participants"]
    out = {}
    for p in participants:
        recorded = entries.get(p, {}).get("annotations", {})
        if not recorded:
            continue
        now = annotation_fingerprints(df.filter(df["participant_id"] == p))
        changed = sorted(v for v, fp in recorded.items() if v in now and now[v] != fp)
        if changed:
            out[p] = changed
    return out


def rebuild_targets(ids: list[str], df) -> dict[str, list[str]]:
    """The participants to rebuild for `--rebuild` ids (videos, or participants), with the ids
    that named each. Online memory formation is sequential, so a video is rebuilt with the whole
    participant that owns it."""
    owner = dict(df.select("video_id", "participant_id").unique().iter_rows())
    known = set(df["participant_id"].unique().to_list())
    out: dict[str, list[str]] = {}
    for i in ids:
        p = i if i in known else owner.get(i)
        if p is None:
            raise DataError(f"--rebuild {i}: no such video or participant in the annotations")
        out.setdefault(p, []).append(i)
    return out


def build_bank(
    bank_path: str | Path,
    participants: list[str] | None = None,
    annotations: str | Path | None = None,
    mode: str = "edited",
    embed_model: str | None = None,
    on_plan: Callable[[dict[str, list[str]]], None] | None = None,
    on_video: Callable[[str, str, int], None] | None = None,
    stop_after: int | None = None,
    episodic: bool = False,
    fts: bool = False,
    jobs: int | None = None,
    rebuild: list[str] | None = None,
    isolate: bool = False,
    on_notice: Callable[[str], None] | None = None,
    executor=None,
    narrations: str | Path | None = None,
    participant: str | None = None,
) -> BankBuild:
    """Build (or resume) a bank. `participants=None` means every participant in the annotations
    (with `rebuild`, only the participants rebuilt). After each participant, offline
    consolidation and enrichment write its inferred knowledge, unless `episodic` (the
    MEMORA-Episodic condition) or a raw bank. `fts` also builds the full-text indexes (only the
    'fts' / 'kuzu' / 'hnsw' retrieval recipes read them).

    `jobs` participants are built side by side in worker processes (each participant is its
    own database; default `auto_jobs`). One job builds in this process (or, with `isolate`, in
    one worker process this one can stop: `memora build` does that), its torch threads chosen
    per batch (ThreadGovernor); parallel workers embed on one thread each, which on 2 cores
    beats two threads spinning against each other.

    Before any work: a built video whose annotation rows changed since is an error naming
    `rebuild` (ids of videos or participants; each rebuilds its whole participant, whose old
    database is kept aside until the new one is complete); the free space must cover an
    estimate from the videos to build. A failure (an exception, not a kill) removes the partial
    files of participants new to the bank, and the bank itself if this build created it; a full
    disk is reported as such. `on_notice(text)` hears what the build decided (rebuilds).
    `executor` (memora_graph.executors.Executor) 'ray' builds each participant in a Ray task
    instead (executors/build.py); everything before and after the building is the same.
    `narrations`: a free-text narration table (CSV, JSONL or Parquet: video_id, start, end, text,
    optional participant; perceive/narrations.py) instead of EPIC annotations; `participant`
    names whose memory it is where the table has no participant column."""
    t_start = time.perf_counter()
    if participants is not None and not list(participants):
        raise DataError("no participants given: name some (P01,P02), or pass None for every participant")
    check_writable(bank_path)  # before anything slow: a path no build can write fails now, not after the model loads
    out = BankBuild()
    t0 = time.perf_counter()
    from memora_graph.paths import epic_dir

    if narrations is not None:
        from memora_graph.perceive.narrations import NarrationReader, load_narrations

        reader = NarrationReader()
        df, durations, out.unknown = load_narrations(narrations, participant, reader, participants=participants)
        classes = reader.classes
        annotations = narrations
    else:
        df = load_annotations(annotations, participants=participants)
        meta = Path(annotations).parent if annotations else None
        meta = meta or epic_dir()
        classes = load_class_tables(meta)
        durations = dict(load_video_info(meta).select("video_id", "duration").iter_rows())
    found = sorted(df["participant_id"].unique().to_list())
    if not found:
        raise DataError(f"{annotations or 'bundled annotations'}: no actions to build")
    if participants:
        missing = sorted(set(participants) - set(found))
        if missing:
            raise DataError(f"{annotations or 'bundled annotations'}: no actions for participant(s) {', '.join(missing)}")
    targets = rebuild_targets(rebuild, df) if rebuild else {}
    if targets and not participants:
        found = sorted(targets)
        df = df.filter(df["participant_id"].is_in(found))
    bank = Bank(bank_path)
    changed = {p: v for p, v in changed_annotations(bank, df, found).items() if p not in targets}
    if changed:
        lines = "; ".join(f"{p}: {', '.join(v)}" for p, v in sorted(changed.items()))
        first = next(iter(sorted(changed.values())))[0]
        raise DataError(f"{annotations or 'bundled annotations'}: the annotations of built video(s) changed since they "
                        f"were built ({lines}); the bank still holds the old ones. Rebuild with them: `memora build "
                        f"{bank.path} --rebuild {first}` (rebuilds the participant that owns the video).")
    plan = {p: sorted(df.filter(df["participant_id"] == p)["video_id"].unique().to_list()) for p in found}
    built = {p: set(e.get("videos", [])) for p, e in bank.manifest()["participants"].items() if p not in targets} \
        if bank.exists() else {}
    needed = space_needed(plan, durations, built)
    check_space(bank, needed)
    out.load_seconds = time.perf_counter() - t0
    if on_plan:
        on_plan(plan)
    created = not bank.exists()
    before = set(bank.manifest()["participants"]) if not created else set()
    new = {p for p in found if p not in before and not bank.db_path(p).exists()}
    aside: dict[str, Path] = {}
    out.jobs = max(1, min(jobs or auto_jobs(len(found)), len(found)))
    opts = dict(mode=mode, stop_after=stop_after, episodic=episodic, fts=fts)
    results: list[BuiltParticipant] = []
    try:
        for p, ids in sorted(targets.items()):
            if p in before or bank.db_path(p).exists():
                aside[p] = set_aside(bank, p)
            if on_notice:
                on_notice(f"rebuilding {p} from its first video ({', '.join(ids)}): memory formation is sequential, "
                          f"so a video is rebuilt with the participant that owns it")
        if executor is not None and executor.remote:
            from memora_graph.pipeline.ray import build_on_ray

            results = build_on_ray(executor, bank, found, df, durations, classes, embed_model, on_video, opts, results,
                                   on_notice)
        elif out.jobs > 1 or isolate:
            results = build_parallel(bank, found, df, durations, classes, embed_model, out.jobs, on_video, opts,
                                      results)
        else:
            t0 = time.perf_counter()
            embedder = get_embedder(embed_model)
            model_seconds = time.perf_counter() - t0
            bank.init(mode=mode, embed_model=embedder.name, consolidated=False)
            governor = ThreadGovernor()  # torch threads per batch: all cores unless other processes are busy
            for p in found:
                results.append(build_one(bank, p, df, durations, classes, embedder, governor,
                                          on_video=(lambda v, n, p=p: on_video(p, v, n)) if on_video else None, **opts))
            out.model_seconds = model_seconds
    except BaseException as exc:
        for p in found:
            bank.abandon_writing(p)  # an unfinished write of this process: checked like any other from now on
        if not isinstance(exc, Exception):
            raise  # an interrupt: like a kill, what is staged stays for a resume
        recorded = set(bank.manifest()["participants"]) if bank.exists() else set()
        # new participants the failure left unrecorded are removed; recorded ones stay, marked
        # unfinished, for a resume (their videos are in the graph)
        undo_build(bank, created, new - recorded, {p: a for p, a in aside.items() if p not in recorded})
        purge_trash(bank, {r.build.participant for r in results})
        if isinstance(exc, DiskFullError) or (isinstance(exc, (OSError, StoreError)) and disk_full(exc, bank.path)):
            raise DiskFullError(f"{bank.path}: no space left on device (needed about {needed / 1e6:.0f} MB for this "
                                f"build). Free some space and re-run it; finished participants are kept.") from exc
        raise
    purge_trash(bank, set(found))
    for r in results:
        out.add(r)
    out.wall_seconds = time.perf_counter() - t_start
    return out

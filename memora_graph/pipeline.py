"""Build a memory bank from EPIC annotations: the library call behind `memora build`."""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from memora_graph.bank import Bank, check_writable
from memora_graph.consolidate import finish_participant
from memora_graph.embed import ThreadGovernor, adaptive_threads, get_embedder
from memora_graph.errors import BankError, DataError, DiskFullError, StoreError
from memora_graph.form.build import ParticipantBuild, Timings, build_participant
from memora_graph.perceive.annotations import load_annotations, load_class_tables, load_video_info
from memora_graph.store import disk_full, disk_full_message, free_bytes


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

    @property
    def segments(self) -> int:
        return sum(p.segments for p in self.participants)

    def add(self, r: _Built) -> None:
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


@dataclass
class _Built:
    """One participant's build and finish, as a worker process returns it."""

    build: ParticipantBuild
    setup_seconds: float
    finish: dict[str, float]
    inferred: dict
    inferred_seconds: float
    embedding_seconds: float
    texts_encoded: int
    threads: dict[int, int] = field(default_factory=dict)  # torch threads -> encode calls
    model_seconds: float = 0.0


def _build_one(bank: Bank, p: str, actions, durations: dict, classes, embedder, governor: ThreadGovernor, *, mode: str,
               stop_after: int | None, episodic: bool, fts: bool, on_video) -> _Built:
    emb0, enc0, calls0 = getattr(embedder, "seconds", 0.0), getattr(embedder, "encoded", 0), dict(governor.calls)
    t0 = time.perf_counter()
    with adaptive_threads(embedder, governor):
        res = build_participant(bank, p, actions, durations, classes, embedder, mode=mode, on_video=on_video,
                                stop_after=stop_after)
    setup = max(time.perf_counter() - t0 - res.timings.total, 0.0)
    t0 = time.perf_counter()
    spent: dict[str, float] = {}
    knowledge = finish_participant(bank, p, embedder, episodic=episodic or mode == "raw", fts=fts, timings=spent)
    inferred = knowledge.counts() if knowledge else {"routines": 0, "preferences": 0}
    res.counts.update({k: inferred[k] for k in ("routines", "preferences")})
    return _Built(res, setup, spent, inferred, time.perf_counter() - t0, getattr(embedder, "seconds", 0.0) - emb0,
                  getattr(embedder, "encoded", 0) - enc0,
                  {k: n - calls0.get(k, 0) for k, n in governor.calls.items() if n > calls0.get(k, 0)})


def auto_jobs(n_participants: int) -> int:
    """Worker processes for a build: one per core (at most 4), and at least two participants per
    worker, since each worker loads its own embedding model (~8 s here)."""
    return max(1, min(os.cpu_count() or 1, 4, n_participants // 2))


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
    instead (executors/build.py); everything before and after the building is the same."""
    t_start = time.perf_counter()
    if participants is not None and not list(participants):
        raise DataError("no participants given: name some (P01,P02), or pass None for every participant")
    check_writable(bank_path)  # before anything slow: a path no build can write fails now, not after the model loads
    out = BankBuild()
    t0 = time.perf_counter()
    df = load_annotations(annotations, participants=participants)
    meta = Path(annotations).parent if annotations else None
    from memora_graph.paths import epic_dir

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
    results: list[_Built] = []
    try:
        for p, ids in sorted(targets.items()):
            if p in before or bank.db_path(p).exists():
                aside[p] = _set_aside(bank, p)
            if on_notice:
                on_notice(f"rebuilding {p} from its first video ({', '.join(ids)}): memory formation is sequential, "
                          f"so a video is rebuilt with the participant that owns it")
        if executor is not None and executor.remote:
            from memora_graph.executors.build import build_on_ray

            results = build_on_ray(executor, bank, found, df, durations, classes, embed_model, on_video, opts, results,
                                   on_notice)
        elif out.jobs > 1 or isolate:
            results = _build_parallel(bank, found, df, durations, classes, embed_model, out.jobs, on_video, opts,
                                      results)
        else:
            t0 = time.perf_counter()
            embedder = get_embedder(embed_model)
            model_seconds = time.perf_counter() - t0
            bank.init(mode=mode, embed_model=embedder.name, consolidated=False)
            governor = ThreadGovernor()  # torch threads per batch: all cores unless other processes are busy
            for p in found:
                results.append(_build_one(bank, p, df, durations, classes, embedder, governor,
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
        _undo(bank, created, new - recorded, {p: a for p, a in aside.items() if p not in recorded})
        _purge_trash(bank, {r.build.participant for r in results})
        if isinstance(exc, DiskFullError) or (isinstance(exc, (OSError, StoreError)) and disk_full(exc, bank.path)):
            raise DiskFullError(f"{bank.path}: no space left on device (needed about {needed / 1e6:.0f} MB for this "
                                f"build). Free some space and re-run it; finished participants are kept.") from exc
        raise
    _purge_trash(bank, set(found))
    for r in results:
        out.add(r)
    out.wall_seconds = time.perf_counter() - t_start
    return out


def _set_aside(bank: Bank, participant: str) -> Path:
    """Move a participant's database and staged videos to BANK/.trash/<participant>-<time>/ and
    drop its manifest entry (kept there as entry.json), for a rebuild."""
    trash = bank.path / ".trash" / f"{participant}-{int(time.time() * 1000)}"
    trash.mkdir(parents=True)
    with bank.participant_lock(participant):
        for f in sorted(bank.path.glob(f"{participant}.kuzu*")):
            os.replace(f, trash / f.name)
        staging = bank.path / ".staging" / participant
        if staging.exists():
            os.replace(staging, trash / "staging")
        entry = {}

        def change(data: dict) -> None:
            entry.update(data["participants"].pop(participant, {}))
            mark = data.get("writing", {}).pop(participant, None)
            if mark is not None and not data["writing"]:
                data.pop("writing")

        if bank.exists():
            bank.update_manifest(change)
        (trash / "entry.json").write_text(json.dumps(entry, sort_keys=True))
    return trash


def _undo(bank: Bank, created: bool, new: set[str], aside: dict[str, Path]) -> None:
    """After a failed build: remove what it left of participants new to the bank, put rebuilt
    participants' old databases back, and remove the bank if this build created it and nothing
    of it remains."""
    for p in sorted(new):
        try:
            bank.forget(p, shared_caches=False)
        except BankError:
            pass
    for p, trash in sorted(aside.items()):
        for f in sorted(bank.path.glob(f"{p}.kuzu*")):
            f.unlink()
        for f in sorted(trash.glob(f"{p}.kuzu*")):
            os.replace(f, bank.path / f.name)
        if (trash / "staging").exists():
            os.replace(trash / "staging", bank.path / ".staging" / p)
        entry = json.loads((trash / "entry.json").read_text() or "{}")
        if entry and bank.exists():
            bank.update_manifest(lambda data, p=p, entry=entry: data["participants"].__setitem__(p, entry))
        shutil.rmtree(trash, ignore_errors=True)
    _drop_empty(bank.path / ".trash")
    if created and bank.path.is_dir():
        try:
            empty = not bank.exists() or not bank.manifest()["participants"]
        except BankError:
            empty = False
        if empty and not any(bank.path.glob("P*.kuzu")):
            shutil.rmtree(bank.path, ignore_errors=True)


def _purge_trash(bank: Bank, participants: set[str]) -> None:
    """Remove the previous databases of rebuilds that are now complete."""
    trash = bank.path / ".trash"
    if trash.is_dir():
        for d in sorted(trash.iterdir()):
            if d.name.split("-", 1)[0] in participants:
                shutil.rmtree(d, ignore_errors=True)
    _drop_empty(trash)


def _drop_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass


# -- worker processes --------------------------------------------------------------------------------

_WORKER: dict = {}


def _worker_init(embed_model: str | None, events, solo: bool = False) -> None:
    """Runs once in each worker process: die with the parent (a killed build must not leave
    workers writing), one thread for torch and BLAS (unless it is the only worker), then load
    the embedding model."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG (Linux)
    except (OSError, AttributeError):
        pass
    if not solo:
        try:
            from threadpoolctl import threadpool_limits

            threadpool_limits(limits=1)
        except ImportError:
            pass
    _WORKER["events"] = events
    _WORKER["solo"] = solo
    t0 = time.perf_counter()
    try:
        import torch

        if not solo:
            torch.set_num_threads(1)
        _WORKER["embedder"] = get_embedder(embed_model)
    except Exception as exc:  # noqa: BLE001 - raised again, as itself, by the first task
        _WORKER["error"] = exc
    _WORKER["model_seconds"] = time.perf_counter() - t0


def _worker_model() -> str:
    if "error" in _WORKER:
        raise _WORKER["error"]
    return _WORKER["embedder"].name


def _worker_build(bank_path: str, p: str, actions, durations: dict, classes, opts: dict) -> _Built:
    _worker_model()
    events = _WORKER["events"]
    governor = ThreadGovernor() if _WORKER.get("solo") else ThreadGovernor(max_threads=1)
    r = _build_one(Bank(bank_path), p, actions, durations, classes, _WORKER["embedder"], governor,
                   on_video=lambda v, n: events.put((p, v, n)), **opts)
    r.model_seconds = _WORKER.pop("model_seconds", 0.0)  # reported by a worker's first participant
    return r


def _build_parallel(bank: Bank, found: list[str], df, durations: dict, classes, embed_model: str | None, jobs: int,
                    on_video, opts: dict, results: list[_Built] | None = None) -> list[_Built]:
    """Build participants in `jobs` worker processes; `results` receives each finished one as
    it arrives. When one fails, the others are stopped at once (killed: a worker stuck in a
    Kùzu call cannot be asked) and the failure is raised."""
    import multiprocessing
    import queue
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    ctx = multiprocessing.get_context("spawn")  # a fresh interpreter: no forked torch / Kùzu threads
    events = ctx.Queue()

    def drain() -> None:
        while True:
            try:
                p, v, n = events.get_nowait()
            except queue.Empty:
                return
            if on_video:
                on_video(p, v, n)

    sizes = df.group_by("participant_id").len().iter_rows()
    order = [p for p, _ in sorted(sizes, key=lambda r: (-r[1], r[0]))]  # largest first: the last to finish is small
    finished: dict[str, _Built] = {}
    results = results if results is not None else []
    pool = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_worker_init,
                               initargs=(embed_model, events, jobs == 1))
    try:
        # every worker starts and loads its model at once; the model loads (or says why it
        # cannot) before the bank is touched
        probes = [pool.submit(_worker_model) for _ in range(jobs)]
        name = probes[0].result()
        bank.init(mode=opts["mode"], embed_model=name, consolidated=False)
        futures = {}
        for p in order:
            actions = df.filter(df["participant_id"] == p)
            videos = set(actions["video_id"].unique().to_list())
            futures[pool.submit(_worker_build, str(bank.path), p, actions,
                                {v: d for v, d in durations.items() if v in videos}, classes, opts)] = p
        pending = set(futures)
        while pending:
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            drain()
            for f in sorted(done, key=lambda f: futures[f]):
                exc = f.exception()
                if exc is None:
                    finished[futures[f]] = f.result()
                    results.append(finished[futures[f]])
            for f in done:
                if f.exception() is not None:
                    raise f.exception()
        drain()
    except BaseException:
        # ProcessPoolExecutor has no public way to stop a running task: kill its processes
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            proc.kill()
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    return [finished[p] for p in found]


# -- video ----------------------------------------------------------------------------------------


@dataclass
class VideoBuild:
    """What `build_from_video` did, with the time split a user needs to size a run."""

    participant: str
    videos: list[dict] = field(default_factory=list)  # per video: id, turns, segments, failed turns, seconds
    counts: dict = field(default_factory=dict)
    decisions: dict = field(default_factory=dict)
    calls: list = field(default_factory=list)  # CallRecords of this run
    timings: Timings = field(default_factory=Timings)  # the builder's split: editor, embedding, staging
    decode_seconds: float = 0.0
    model_seconds: float = 0.0  # waiting for model replies (sum of call latencies)
    load_seconds: float = 0.0  # loading the embedding model
    finish_seconds: float = 0.0  # the bulk load into the graph
    inferred_seconds: float = 0.0  # offline consolidation and enrichment after the build (and --fts indexes)
    wall_seconds: float = 0.0
    loaded: bool = False  # staged videos were loaded into the graph (this run's or an interrupted one's)

    @property
    def segments(self) -> int:
        return sum(v.get("segments", 0) for v in self.videos)

    @property
    def graph_seconds(self) -> float:
        """The build's own work: everything except decoding, loading the embedding model, waiting
        for the model and the offline consolidation that follows."""
        return max(self.wall_seconds - self.decode_seconds - self.model_seconds - self.load_seconds
                   - self.inferred_seconds, 0.0)


def _model_backend(name: str, base_url: str | None, model: str | None, call_log, options: dict | None):
    from memora_graph.llm import ModelUnavailableError, get_backend

    opts = dict(options or {})
    if name == "openai":
        opts.update({k: v for k, v in (("base_url", base_url), ("model", model)) if v})
    elif name == "vllm":
        if not model:
            raise ModelUnavailableError("--backend vllm loads the model in-process: pass --perception-model NAME")
        opts["model"] = model
    return get_backend(name, call_log=call_log, **opts)


def build_from_video(
    bank_path: str | Path,
    video: str | Path,
    participant: str,
    *,
    video_id: str | None = None,
    backend: str = "openai",
    base_url: str | None = None,
    perception_model: str | None = None,
    editor_model: str | None = None,
    editor_base_url: str | None = None,
    audio: bool | None = None,
    embed_model: str | None = None,
    decode=None,
    backend_options: dict | None = None,
    on_video: Callable[[str, int], None] | None = None,
    on_segment: Callable[[str, int, str | None], None] | None = None,
    episodic: bool = False,
    fts: bool = False,
    consolidation: str | None = None,
    consolidation_model: str | None = None,
    concurrency: int = 1,
) -> VideoBuild:
    """Build (or resume) one participant's memory from a video file or a directory of videos:
    10 s clips -> VLM perception -> LLM entity editor -> the participant's graph.

    Nothing is written before every file has been probed and the backend is known to do
    perception. Consolidation and enrichment then run by model too (`consolidation="llm"`, the
    default here; the consolidation model defaults to the editor's) or by the deterministic rules. `audio=None` sends audio to audio-capable models only (by model name).
    `on_video(video_id, n_clips)` and `on_segment(video_id, turn, error_or_None)` report progress.
    `concurrency`: videos perceived at once (each video's clips in order), and consolidation calls
    in flight; 1 runs everything one call at a time.
    """
    import dataclasses

    from memora_graph.form.llm_editor import LLMEditorPolicy
    from memora_graph.llm import CallLog
    from memora_graph.perceive.video import DecodeOptions, list_videos, probe_video
    from memora_graph.perceive.vlm import VLMPerception

    t_start = time.perf_counter()
    bank = Bank(check_writable(bank_path))
    bank.db_path(participant)  # a bad participant id fails before any work
    files = list_videos(video)
    if video_id and len(files) > 1:
        raise DataError(f"{video}: --video-id names one video, but this directory holds {len(files)}")
    log = CallLog()
    perception_backend = _model_backend(backend, base_url, perception_model, log, backend_options)
    perceiver = VLMPerception(perception_backend, participant, audio=audio)
    editor_backend = perception_backend
    if editor_model or editor_base_url:
        editor_backend = _model_backend(backend, editor_base_url or base_url, editor_model or perception_model, log,
                                        backend_options)
    policy = LLMEditorPolicy(editor_backend)
    processors = "deterministic"
    if (consolidation or "llm") == "llm" and not episodic:  # the paper's consolidation / enrichment models
        from memora_graph.consolidate.llm import make_llm_processors

        processors = make_llm_processors(_model_backend(
            backend, editor_base_url or base_url, consolidation_model or editor_model or perception_model, CallLog(),
            backend_options), concurrency=concurrency)
    opts = decode or DecodeOptions()
    opts = dataclasses.replace(opts, audio=opts.audio and perceiver.audio)
    infos = [probe_video(f, video_id) for f in files]
    seen: dict[str, Path] = {}
    for info in infos:
        if info.video_id in seen:
            raise DataError(f"{info.path} and {seen[info.video_id]} would both be video {info.video_id!r}; rename one")
        seen[info.video_id] = info.path

    out = VideoBuild(participant)
    t0 = time.perf_counter()
    embedder = get_embedder(embed_model)
    out.load_seconds = time.perf_counter() - t0
    created = not bank.exists()
    bank.init(mode="edited", embed_model=embedder.name, consolidated=False)
    new = participant not in bank.manifest()["participants"] and not bank.db_path(participant).exists()
    try:
        with bank.participant_lock(participant):
            _build_videos(bank, participant, embedder, policy, log, perceiver, infos, opts, out, on_video, on_segment,
                          concurrency)
        t0 = time.perf_counter()
        entry = bank.manifest().get("participants", {}).get(participant, {})
        if out.loaded or "inferred" not in entry or bank.writing_here(participant):  # a resume with nothing new: done
            finish_participant(bank, participant, embedder, episodic=episodic, fts=fts, processors=processors)
        out.inferred_seconds = time.perf_counter() - t0
    except Exception as exc:
        # nothing half-written: what this run staged is gone (see _build_videos), a participant or
        # a bank this run created is removed
        bank.abandon_writing(participant)
        recorded = bank.exists() and participant in bank.manifest()["participants"]
        _undo(bank, created, {participant} if new and not recorded else set(), {})
        if isinstance(exc, (OSError, StoreError)) and not isinstance(exc, DiskFullError) and disk_full(exc, bank.path):
            raise DiskFullError(disk_full_message(bank.path)) from exc
        raise
    out.calls = list(log.records)
    out.model_seconds = sum(r.latency_s for r in log.records)
    out.wall_seconds = time.perf_counter() - t_start
    return out


def _build_videos(bank: Bank, participant: str, embedder, policy, log, perceiver, infos, opts, out: VideoBuild,
                  on_video, on_segment, concurrency: int = 1) -> None:
    """Perceive, edit and stage each video, then load them all. A video that fails (a decode
    error halfway through, a model server that goes away) removes what this run staged, so the
    database and staging are as they were; it is reported naming the file."""
    from memora_graph.form.build import ParticipantBuilder
    from memora_graph.perceive.video import segment_video
    from memora_graph.embed import torch_threads

    builder = ParticipantBuilder(bank, participant, embedder, policy=policy, call_log=log)
    todo = [info for info in infos if info.video_id not in builder.done]

    def perceive(info):
        n_clips = info.n_segments(opts.segment_seconds)
        if on_video:
            on_video(info.video_id, n_clips)
        perceived = []
        for pc in perceiver.perceive(_timed(segment_video(info.path, opts, info=info), out)):
            perceived.append(pc)
            if on_segment:
                on_segment(info.video_id, pc.clip.turn_id, pc.error)
        return perceived

    pool = None
    try:
        with torch_threads(1):  # small embedding batches: one torch thread is faster on 2 cores
            if concurrency > 1 and len(todo) > 1:
                # Perception of different videos is in flight together (each video's clips in order:
                # the working summary chains them); the editor takes the videos one after another.
                from concurrent.futures import ThreadPoolExecutor

                pool = ThreadPoolExecutor(max_workers=min(concurrency, len(todo)), thread_name_prefix="perceive")
                ahead = {info.video_id: pool.submit(perceive, info) for info in todo}
            else:
                ahead = {}
            for info in infos:
                if info.video_id in builder.done:
                    out.videos.append({"video": info.video_id, "skipped": True})
                    continue
                t_video = time.perf_counter()
                decode_before = out.decode_seconds
                perceived = ahead[info.video_id].result() if ahead else perceive(info)
                segments = [pc.segment for pc in perceived if pc.segment is not None]
                timings, dropped = builder.build_segments(info.video_id, segments, info.duration, n_turns=len(perceived))
                out.timings.add(timings)
                out.videos.append({
                    "video": info.video_id, "duration_s": round(info.duration, 2), "turns": len(perceived),
                    "segments": len(segments) - len(dropped),
                    "perception_failed": [pc.clip.turn_id for pc in perceived if pc.segment is None],
                    "editor_failed": dropped, "decode_s": round(out.decode_seconds - decode_before, 3),
                    "seconds": round(time.perf_counter() - t_video, 3),
                })
            out.loaded = bool(builder.staged)
            t0 = time.perf_counter()
            builder.finish()
            out.finish_seconds = time.perf_counter() - t0
            out.counts = builder.counts()
            out.decisions = builder.decisions()
            bank.record_participant(participant, sorted(builder.done), out.counts)
    except Exception:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        builder.discard()
        raise
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
        builder.close()


def _timed(clips, out: VideoBuild):
    """Yield from the decoder, adding the time spent inside it to `out.decode_seconds`."""
    it = iter(clips)
    while True:
        t0 = time.perf_counter()
        try:
            clip = next(it)
        except StopIteration:
            out.decode_seconds += time.perf_counter() - t0
            return
        out.decode_seconds += time.perf_counter() - t0
        yield clip

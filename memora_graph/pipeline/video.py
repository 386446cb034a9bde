"""Build one participant's memory from video files: the library call behind `memora build --video`."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from memora_graph.bank import Bank, check_writable
from memora_graph.consolidate import finish_participant
from memora_graph.embed import get_embedder
from memora_graph.errors import DataError, DiskFullError, StoreError
from memora_graph.form.build import Timings
from memora_graph.pipeline.rollback import undo_build
from memora_graph.store import disk_full, disk_full_message


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
        undo_build(bank, created, {participant} if new and not recorded else set(), {})
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

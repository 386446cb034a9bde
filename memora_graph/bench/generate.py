"""Generate a MEMORA-Bench suite (EAM-QA + Planning Replay + Generalize) from annotations.

One call turns an EPIC-style annotation table into the official release layout, with no LLM
and no memory bank (except the optional object registry that Replay enrichment may read).
Everything is a function of the annotations, the seed and the registry: a participant's
files are the same whether it is generated alone or with the whole cohort.
"""

from __future__ import annotations

import random
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import polars as pl

from memora_graph.bench.behaviour import Behaviour, build_behaviours
from memora_graph.bench.generate_generalize import GeneralizeConfig, generate_generalize
from memora_graph.bench.generate_qa import (
    QuestionCandidate, QaConfig, QaGenerator, VectorCache, balanced_letters, control_quota, dedup_pool, rank_candidates,
    rewrite_participant, select_answerable, select_controls,
)
from memora_graph.bench.generate_replay import ReplayConfig, generate_replay
from memora_graph.bench.tasks import (
    ABSTAIN_INSTRUCTION, LETTERS, OPTION_E, QA_TYPES, BenchSuite, EamQaFile, EamQuestion, ParticipantTasks, ReplayTask,
    normalize_participants, write_json, write_suite,
)
from memora_graph.errors import DataError

REPLAY_AUDIT_DIR = Path("planning") / "audit" / "replay_filtered"
MANIFEST = "generation.json"


@dataclass
class GenerateConfig:
    """Knobs with the paper's defaults; the seed is an argument of generate_suite."""

    qa: QaConfig = field(default_factory=QaConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    generalize_targets_per_action: int = 2
    generalize_max_transfer: int = 6


@dataclass
class GenerationReport:
    seed: int
    participants: list[str]
    seconds: float = 0.0
    per_participant: dict[str, dict[str, Any]] = field(default_factory=dict)
    filtered_replay: dict[str, list[ReplayTask]] = field(default_factory=dict)
    semantic_dedup: str = "off"

    def totals(self) -> dict[str, int]:
        out = Counter()
        for stats in self.per_participant.values():
            for key in ("answerable", "e_correct", "replay", "generalize"):
                out[key] += stats[key]
        return dict(out)


def _rng(seed: int, pid: str, purpose: str) -> random.Random:
    # string seeds are hashed with SHA-512 by `random`, so streams are stable across processes
    return random.Random(f"{seed}:{pid}:{purpose}")


def _question(pid: str, c: QuestionCandidate, position: int, rng: random.Random, scope: list[str]) -> EamQuestion:
    options = list(c.distractors)
    rng.shuffle(options)
    options.insert(position, c.answer)
    video_ids = sorted(c.video_ids)
    return EamQuestion(
        question_id="pending", question=c.stem + ABSTAIN_INSTRUCTION, choices=options + [OPTION_E],
        correct_answer=LETTERS[position], is_multiple_choice=True, qa_type=c.qa_type, ground_truth=c.answer,
        video_id=c.video_id or video_ids[0], video_ids=video_ids, participant_id=pid, video_scope=scope,
        num_videos=len(video_ids), is_unanswerable=False, reasoning_depth=c.depth,
        audit={"template": c.template, "evidence": c.evidence, "support_keys": c.support_keys},
    )


def _control(pid: str, donor: str, c: QuestionCandidate, donor_videos: int, rng: random.Random) -> EamQuestion:
    options = [c.answer, *c.distractors]
    rng.shuffle(options)
    options = [rewrite_participant(o, donor, pid) for o in options]
    masked = f"{pid}_???"
    return EamQuestion(
        question_id="pending", question=rewrite_participant(c.stem, donor, pid) + ABSTAIN_INSTRUCTION,
        choices=options + [OPTION_E], correct_answer="E", is_multiple_choice=True, qa_type=c.qa_type,
        ground_truth=c.answer, video_id=masked, video_ids=[masked] * len(c.video_ids), participant_id=pid,
        video_scope=[masked] * donor_videos, num_videos=len(c.video_ids), is_unanswerable=True,
        source_participant=donor.lower(), target_participant=pid.lower(), reasoning_depth=c.depth,
        audit={"template": c.template, "donor_participant": donor, "donor_evidence": c.evidence,
               "support_keys": c.support_keys, "target_support": 0},
    )


def _eam_file(pid: str, b: Behaviour, kept: list[QuestionCandidate], controls: list[tuple[str, QuestionCandidate]],
              donors: dict[str, Behaviour], seed: int, dedup: str, dropped: dict) -> EamQaFile:
    rng = _rng(seed, pid, "assemble")
    positions = balanced_letters(len(kept), rng)
    items = [_question(pid, c, pos, rng, b.videos) for c, pos in zip(kept, positions)]
    items += [_control(pid, donor, c, len(donors[donor].videos), rng) for donor, c in controls]
    rng.shuffle(items)
    for i, q in enumerate(items):
        q.question_id = f"{pid.lower()}_q{i:04d}"
    answerable = [q for q in items if not q.is_unanswerable]
    n_u = len(items) - len(answerable)
    metadata = {
        "format": "multiple_choice_5",
        "option_e": OPTION_E,
        "source": f"EAM-QA source: memora-graph rule generator (seed {seed})",
        "n": len(answerable),
        "by_type": {t: sum(q.qa_type == t for q in answerable) for t in QA_TYPES},
        "skipped": 0,
        "eam_qa_unanswerable_augmentation": {
            "n_answerable": len(answerable), "n_unanswerable": n_u,
            "unanswerable_ratio": n_u / len(items) if items else 0.0,
            "donor_pids": sorted({d.lower() for d, _ in controls}),
        },
        "generator": {
            "seed": seed, "semantic_dedup": dedup,
            "by_depth": {str(d): sum(q.reasoning_depth == d for q in answerable) for d in (1, 2, 3)},
            **dropped,
        },
    }
    return EamQaFile(questions=items, metadata=metadata)


def generate_suite(
    annotations: pl.DataFrame | None = None,
    participants: list[str] | None = None,
    seed: int = 42,
    registries: dict[str, list[dict]] | None = None,
    config: GenerateConfig | None = None,
    embedder: Any = "default",
    class_dir: str | Path | None = None,
) -> tuple[BenchSuite, GenerationReport]:
    """Build the suite for `participants` (default: everyone in the annotations).

    `embedder`: "default" uses memora_graph.embed.get_embedder() for the cosine >= 0.95 dedup;
    None skips semantic dedup (exact dedup still applies); any object with .encode() is used as is.
    `registries`: participant id -> the bank's object registry (list of {memory_id, memory_name,
    color, material, location}); used only to enrich Replay steps and ground Generalize steps.
    E-correct controls draw donor questions from every participant in the annotations.
    """
    t0 = time.perf_counter()
    config = config or GenerateConfig()
    if annotations is None:
        from memora_graph.perceive.annotations import load_annotations

        annotations = load_annotations()
    behaviours = build_behaviours(annotations, class_dir)
    if not behaviours:
        raise DataError("the annotation table has no rows")
    wanted = normalize_participants(participants)
    targets = sorted(wanted) if wanted else sorted(behaviours)
    unknown = [p for p in targets if p not in behaviours]
    if unknown:
        raise DataError(f"no annotations for participant(s) {', '.join(unknown)}; available: {', '.join(sorted(behaviours))}")
    registries = {k.upper(): v for k, v in (registries or {}).items()}
    if embedder == "default":
        from memora_graph.embed import get_embedder

        embedder = get_embedder()
    dedup = f"{getattr(embedder, 'name', type(embedder).__name__)} cosine >= {config.qa.dedup_threshold}" if embedder else "off"

    ranked: dict[str, dict] = {}
    donor_pools: dict[str, list[QuestionCandidate]] = {}
    for pid, b in behaviours.items():
        cands = QaGenerator(b, _rng(seed, pid, "qa"), config.qa.thresholds).all()
        ranked[pid] = rank_candidates(cands, _rng(seed, pid, "rank"))
        # donor pools never depend on the embedder, so controls are the same in any run
        donor_pools[pid], _ = select_answerable(ranked[pid], config.qa, len(b.videos))

    vectors = None
    if embedder is not None:  # one model call for every target's likely dedup texts
        vectors = VectorCache(embedder)
        vectors.prime([t for pid in targets for t in dedup_pool(ranked[pid], config.qa, len(behaviours[pid].videos))])

    suite = BenchSuite()
    report = GenerationReport(seed=seed, participants=targets, semantic_dedup=dedup)
    gen_config = GeneralizeConfig(targets_per_action=config.generalize_targets_per_action,
                                  max_transfer=config.generalize_max_transfer, seed=seed)
    for pid in targets:
        b = behaviours[pid]
        kept, dropped = select_answerable(ranked[pid], config.qa, len(b.videos), vectors)
        n_controls = control_quota(len(kept), config.qa.unanswerable_ratio)
        controls = select_controls(pid, b.facts(), Counter(c.qa_type for c in kept), donor_pools, n_controls,
                                   _rng(seed, pid, "controls"))
        eam = _eam_file(pid, b, kept, controls, behaviours, seed, dedup, dropped)
        registry = registries.get(pid)
        replay = generate_replay(b, registry, config.replay)
        generalize = generate_generalize(b, registry, gen_config)
        suite.participants[pid] = ParticipantTasks(pid, eam, replay.tasks, generalize)
        report.filtered_replay[pid] = replay.filtered
        answerable = [q for q in eam.questions if not q.is_unanswerable]
        report.per_participant[pid] = {
            "videos": len(b.videos),
            "answerable": len(answerable),
            "e_correct": len(eam.questions) - len(answerable),
            "answerable_by_type": dict(Counter(q.qa_type for q in answerable)),
            "e_correct_by_type": dict(Counter(q.qa_type for q in eam.questions if q.is_unanswerable)),
            "replay": len(replay.tasks), "replay_candidates": replay.n_candidates,
            "replay_filtered": len(replay.filtered),
            "generalize": len(generalize),
            **dropped,
        }
    report.seconds = time.perf_counter() - t0
    return suite, report


def write_generated(suite: BenchSuite, report: GenerationReport, out: str | Path) -> list[Path]:
    """The release files, the repeat-rate audit bucket and a generation.json manifest."""
    out = Path(out)
    written = write_suite(suite, out)
    for pid, tasks in report.filtered_replay.items():
        if tasks:
            path = out / REPLAY_AUDIT_DIR / f"{pid.lower()}.json"
            write_json(path, [t.model_dump(exclude_none=True) for t in tasks])
            written.append(path)
    manifest = {
        "generator": "memora-graph bench generate", "seed": report.seed, "participants": report.participants,
        "semantic_dedup": report.semantic_dedup, "seconds": round(report.seconds, 2),
        "totals": report.totals(), "per_participant": report.per_participant,
        "note": "EAM-QA items carry an `audit` field with their evidence; strip it (EamQuestion.answering_view) "
                "before showing an item to an answering agent.",
    }
    write_json(out / MANIFEST, manifest)
    written.append(out / MANIFEST)
    return written

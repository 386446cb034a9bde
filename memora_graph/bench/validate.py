"""Check a MEMORA-Bench release folder and count what it holds, per participant and type.

Loading already validates every item (tasks.load_suite names the file and item at fault);
this adds the cross-item checks (metadata counts agree with the items, controls answer E on
masked ids) and the counts table that `memora bench validate` prints.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

from memora_graph.bench.tasks import GENERALIZE_TYPES, QA_TYPES, REPLAY_TYPES, BenchSuite, load_suite

# The paper's full release (18 participants), for comparison with a generated suite.
OFFICIAL_RELEASE = {"participants": 18, "answerable": 2212, "e_correct": 551, "replay": 207, "generalize": 153}


@dataclass
class ParticipantCounts:
    participant_id: str
    answerable: int = 0
    e_correct: int = 0
    answerable_by_type: dict[str, int] = field(default_factory=dict)
    e_correct_by_type: dict[str, int] = field(default_factory=dict)
    replay: int = 0
    replay_steps: int = 0
    replay_by_type: dict[str, int] = field(default_factory=dict)
    generalize: int = 0
    generalize_by_type: dict[str, int] = field(default_factory=dict)

    @property
    def questions(self) -> int:
        return self.answerable + self.e_correct


@dataclass
class ValidationReport:
    root: str
    rows: list[ParticipantCounts]
    problems: list[str]

    def total(self) -> ParticipantCounts:
        out = ParticipantCounts("total")
        for r in self.rows:
            out.answerable += r.answerable
            out.e_correct += r.e_correct
            out.replay += r.replay
            out.replay_steps += r.replay_steps
            out.generalize += r.generalize
            for name in ("answerable_by_type", "e_correct_by_type", "replay_by_type", "generalize_by_type"):
                merged = Counter(getattr(out, name))
                merged.update(getattr(r, name))
                setattr(out, name, dict(merged))
        return out

    def as_dict(self) -> dict:
        return {"root": self.root, "participants": [asdict(r) for r in self.rows],
                "total": asdict(self.total()), "problems": self.problems}


def count_suite(suite: BenchSuite) -> list[ParticipantCounts]:
    rows = []
    for pid, entry in suite.participants.items():
        row = ParticipantCounts(pid)
        if entry.eam_qa:
            qs = entry.eam_qa.questions
            row.answerable = sum(not q.is_unanswerable for q in qs)
            row.e_correct = sum(q.is_unanswerable for q in qs)
            row.answerable_by_type = dict(Counter(q.qa_type for q in qs if not q.is_unanswerable))
            row.e_correct_by_type = dict(Counter(q.qa_type for q in qs if q.is_unanswerable))
        if entry.replay:
            row.replay = len(entry.replay)
            row.replay_steps = sum(t.num_steps for t in entry.replay)
            row.replay_by_type = dict(Counter(t.task_type for t in entry.replay))
        if entry.generalize:
            row.generalize = len(entry.generalize)
            row.generalize_by_type = dict(Counter(t.task_type for t in entry.generalize))
        rows.append(row)
    return rows


def check_suite(suite: BenchSuite) -> list[str]:
    """Cross-item problems (the items themselves were validated while loading)."""
    problems = []
    for pid, entry in suite.participants.items():
        if not entry.eam_qa:
            continue
        qs, meta = entry.eam_qa.questions, entry.eam_qa.metadata
        where = f"eam_qa/questions/{pid.lower()}.json"
        answerable = [q for q in qs if not q.is_unanswerable]
        if "n" in meta and meta["n"] != len(answerable):
            problems.append(f"{where}: metadata.n is {meta['n']} but {len(answerable)} questions are answerable")
        by_type = meta.get("by_type")
        if isinstance(by_type, dict):
            actual = Counter(q.qa_type for q in answerable)
            for t in QA_TYPES:
                if by_type.get(t, 0) != actual.get(t, 0):
                    problems.append(f"{where}: metadata.by_type.{t} is {by_type.get(t, 0)} but {actual.get(t, 0)} answerable {t} questions")
        aug = meta.get("eam_qa_unanswerable_augmentation")
        if isinstance(aug, dict) and "n_unanswerable" in aug and aug["n_unanswerable"] != len(qs) - len(answerable):
            problems.append(f"{where}: metadata n_unanswerable is {aug['n_unanswerable']} but {len(qs) - len(answerable)} questions are E-correct")
        for i, q in enumerate(qs):
            if q.is_unanswerable and any("???" not in v for v in q.video_ids):
                problems.append(f"{where}: questions[{i}] ({q.question_id}): an E-correct control lists unmasked video ids {q.video_ids}")
    return problems


def validate_suite(root: str | Path | None = None, participants: list[str] | None = None) -> ValidationReport:
    """Load (schema check; raises DataError naming the file and item) and count a release folder."""
    suite = load_suite(root, participants)
    return ValidationReport(root=str(suite.root), rows=count_suite(suite), problems=check_suite(suite))


def _split(by: dict[str, int], extra: dict[str, int], key: str) -> str:
    return f"{by.get(key, 0)}+{extra.get(key, 0)}"


def render_table(report: ValidationReport) -> str:
    """Plain-text tables: EAM-QA (answerable+E-correct per type) and planning per type."""
    head = ["participant", "questions", "answerable", "E-correct", *QA_TYPES, "replay", "steps", "generalize"]
    rows = []
    for r in [*report.rows, report.total()]:
        rows.append([
            r.participant_id, str(r.questions), str(r.answerable), str(r.e_correct),
            *[_split(r.answerable_by_type, r.e_correct_by_type, t) for t in QA_TYPES],
            str(r.replay), str(r.replay_steps), str(r.generalize),
        ])
    out = [_table(head, rows), "(type columns: answerable+E-correct)", ""]
    short = {"object_retrieval_setup": "retrieval", "cleanup_organization": "cleanup", "multi_step_cooking": "cooking",
             "meal_preparation": "meal_prep", "routine_reproduction": "routine", "fully_novel": "novel"}
    head2 = ["participant", *[short.get(t, t) for t in REPLAY_TYPES], "|", *[short.get(t, t) for t in GENERALIZE_TYPES]]
    rows2 = [[r.participant_id, *[str(r.replay_by_type.get(t, 0)) for t in REPLAY_TYPES], "|",
              *[str(r.generalize_by_type.get(t, 0)) for t in GENERALIZE_TYPES]] for r in [*report.rows, report.total()]]
    out += ["Planning: Replay types | Generalize types", _table(head2, rows2), ""]
    ref = OFFICIAL_RELEASE
    total = report.total()
    out.append(
        f"This folder: {len(report.rows)} participants, {total.answerable:,} answerable + {total.e_correct:,} E-correct "
        f"= {total.questions:,} EAM-QA; {total.replay} Replay; {total.generalize} Generalize."
    )
    out.append(
        f"Official release: {ref['participants']} participants, {ref['answerable']:,} answerable + {ref['e_correct']:,} "
        f"E-correct = {ref['answerable'] + ref['e_correct']:,} EAM-QA; {ref['replay']} Replay; {ref['generalize']} Generalize."
    )
    if report.problems:
        out += ["", f"{len(report.problems)} problem(s):", *[f"  - {p}" for p in report.problems]]
    return "\n".join(out)


def _table(head: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    line = lambda cells: "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))  # noqa: E731
    return "\n".join([line(head), line(["-" * w for w in widths]), *[line(r) for r in rows]])

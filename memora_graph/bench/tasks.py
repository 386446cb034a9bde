"""MEMORA-Bench task records and the reader/writer of the official release layout.

A release folder holds `eam_qa/questions/pXX.json` ({"questions": [...], "metadata": {...}})
and `planning/suites/{replay,generalize}/pXX.json` (JSON arrays). The bundled calibration
cohort (P01-P04) is one such folder; a full release or a generated suite is another. Loading
validates every item and names the file, item and field at fault.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from memora_graph.errors import DataError
from memora_graph.paths import calibration_dir

OPTION_E = "The information is not available based on the given context"
ABSTAIN_INSTRUCTION = (
    "\n\nIMPORTANT: If the information needed to answer this question is not available in your "
    "memory or context, you MUST select option E. Only select A-D if you are confident the "
    "answer is supported by information you have access to."
)
LETTERS = ("A", "B", "C", "D", "E")
QA_TYPES = ("SPref", "SHabit", "SRoutine", "ERecall")
REPLAY_TYPES = (
    "object_retrieval_setup", "cleanup_organization", "multi_step_cooking",
    "meal_preparation", "routine_reproduction",
)
GENERALIZE_TYPES = ("transfer", "composition", "fully_novel")
GENERALIZE_PREFIX = "generalize_"

EAM_DIR = Path("eam_qa") / "questions"
REPLAY_DIR = Path("planning") / "suites" / "replay"
GENERALIZE_DIR = Path("planning") / "suites" / "generalize"

_CLOCK = re.compile(r"^\d{2}:\d{2}:\d{2}(\.\d+)?$")
_FILE_PID = re.compile(r"^p\d+$")

QaType = Literal["SPref", "SHabit", "SRoutine", "ERecall"]
ReplayType = Literal[
    "object_retrieval_setup", "cleanup_organization", "multi_step_cooking",
    "meal_preparation", "routine_reproduction",
]
GeneralizeType = Literal["transfer", "composition", "fully_novel"]


class _Record(BaseModel):
    # A full release may carry keys this project does not use; they are kept, not rejected.
    model_config = ConfigDict(extra="allow")


# ---------------------------------------------------------------------------------------------
# EAM-QA
# ---------------------------------------------------------------------------------------------

class EamQuestion(_Record):
    question_id: str = Field(min_length=1)
    question: str = Field(min_length=1)
    choices: list[str]
    correct_answer: Literal["A", "B", "C", "D", "E"]
    is_multiple_choice: bool = True
    qa_type: QaType
    ground_truth: str
    video_id: str
    video_ids: list[str]
    participant_id: str
    video_scope: list[str]
    num_videos: int = Field(ge=0)
    is_unanswerable: bool
    source_participant: str | None = None
    target_participant: str | None = None
    # Generated items only: 1 for single-hop, 2/3 for multi-hop (chained within-video steps).
    reasoning_depth: int | None = Field(default=None, ge=1, le=3)
    # Generated items only: the evidence (videos, timestamps, counts). Never shown to an agent.
    audit: dict[str, Any] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> EamQuestion:
        if len(self.choices) != 5:
            raise ValueError(f"choices: expected 5 options (A-E), got {len(self.choices)}")
        if any(not c.strip() for c in self.choices):
            raise ValueError("choices: an option is empty")
        if self.choices[4] != OPTION_E:
            raise ValueError(f"choices: option E must be {OPTION_E!r}, got {self.choices[4]!r}")
        if self.is_unanswerable:
            if self.correct_answer != "E":
                raise ValueError(f"correct_answer: an E-correct control must answer 'E', got {self.correct_answer!r}")
            if not self.source_participant or not self.target_participant:
                raise ValueError("source_participant/target_participant: required on an E-correct control")
        elif self.correct_answer == "E":
            raise ValueError("correct_answer: 'E' on an item with is_unanswerable false")
        return self

    def answering_view(self) -> dict[str, Any]:
        """What the answering agent receives: no key, no ground truth, no provenance, no audit.

        qa_type is kept because the runtime's pattern search filters documents by question type;
        video_ids/video_scope set the participant context.
        """
        return {
            "question_id": self.question_id, "participant_id": self.participant_id,
            "qa_type": self.qa_type, "question": self.question, "choices": list(self.choices),
            "video_id": self.video_id, "video_ids": list(self.video_ids),
            "video_scope": list(self.video_scope),
        }


class EamQaFile(BaseModel):
    questions: list[EamQuestion]
    metadata: dict[str, Any] = Field(default_factory=dict)


# ---------------------------------------------------------------------------------------------
# Planning
# ---------------------------------------------------------------------------------------------

class MatchedObject(_Record):
    color: str = ""
    material: str = ""
    location: str = ""
    memory_id: str
    memory_name: str


class ReplayStep(_Record):
    narration_id: str = Field(min_length=1)
    narration: str
    verb: str
    noun: str
    start_time: str
    end_time: str
    enriched_narration: str | None = None
    matched_object: MatchedObject | None = None

    @model_validator(mode="after")
    def _consistent(self) -> ReplayStep:
        for name in ("start_time", "end_time"):
            value = getattr(self, name)
            if not _CLOCK.match(value):
                raise ValueError(f"{name}: expected HH:MM:SS.ss, got {value!r}")
        if (self.enriched_narration is None) != (self.matched_object is None):
            raise ValueError("enriched_narration and matched_object: present together or not at all")
        return self


class ReplayTask(_Record):
    task_id: str = Field(min_length=1)
    participant_id: str
    video_id: str
    task_type: ReplayType
    task_query: str = Field(min_length=1)
    ground_truth_steps: list[ReplayStep] = Field(min_length=1)
    num_steps: int
    time_span_seconds: float = Field(ge=0)
    primary_objects: list[str]
    primary_verbs: list[str]
    video_ids: list[str] | None = None
    repeat_rate: float | None = None
    audit: dict[str, Any] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> ReplayTask:
        if self.task_id.startswith(GENERALIZE_PREFIX):
            raise ValueError(f"task_id: a Replay task must not start with {GENERALIZE_PREFIX!r}")
        if self.num_steps != len(self.ground_truth_steps):
            raise ValueError(f"num_steps: {self.num_steps} but {len(self.ground_truth_steps)} ground_truth_steps")
        return self


class GeneralizeTask(_Record):
    task_id: str = Field(min_length=1)
    task_type: GeneralizeType
    task_query: str = Field(min_length=1)
    video_id: str
    participant_id: str
    source_action: str | None = None
    source_object: str | None = None
    target_object: str | None = None
    components: list[str] | None = None
    ground_truth_steps: list[str] = Field(min_length=1)
    rationale: str = ""
    video_ids: list[str] | None = None
    audit: dict[str, Any] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> GeneralizeTask:
        if not self.task_id.startswith(GENERALIZE_PREFIX):
            raise ValueError(f"task_id: a Generalize task id starts with {GENERALIZE_PREFIX!r}, got {self.task_id!r}")
        if self.task_type == "transfer":
            missing = [k for k in ("source_action", "source_object", "target_object") if not getattr(self, k)]
            if missing:
                raise ValueError(f"{', '.join(missing)}: required on a transfer task")
        if self.task_type == "composition" and not self.components:
            raise ValueError("components: required on a composition task")
        if any(not s.strip() for s in self.ground_truth_steps):
            raise ValueError("ground_truth_steps: a step is empty")
        return self


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------

def _read_json(path: Path) -> Any:
    if not path.exists():
        raise DataError(f"{path}: file not found")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not UTF-8 text ({exc})") from None


def _describe(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors()[:3]:
        loc = ".".join(str(x) for x in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"field '{loc}': {msg}" if loc else msg)
    more = len(exc.errors()) - 3
    return "; ".join(parts) + (f"; and {more} more" if more > 0 else "")


def _item_label(container: str, index: int, raw: Any, id_key: str) -> str:
    ident = raw.get(id_key) if isinstance(raw, dict) else None
    return f"{container}[{index}]" + (f" ({id_key} {ident!r})" if ident else "")


def _check_participant(path: Path, label: str, participant_id: str) -> None:
    stem = path.stem.lower()
    if _FILE_PID.match(stem) and participant_id.lower() != stem:
        raise DataError(f"{path}: {label}: field 'participant_id': {participant_id!r} does not belong in {path.name}")


def _validate_items(path: Path, items: Any, model: type[BaseModel], container: str, id_key: str) -> list:
    if not isinstance(items, list):
        raise DataError(f"{path}: {container}: expected a JSON array, got {type(items).__name__}")
    out, seen = [], {}
    for i, raw in enumerate(items):
        label = _item_label(container, i, raw, id_key)
        if not isinstance(raw, dict):
            raise DataError(f"{path}: {label}: expected a JSON object, got {type(raw).__name__}")
        try:
            record = model.model_validate(raw)
        except ValidationError as exc:
            raise DataError(f"{path}: {label}: {_describe(exc)}") from None
        ident = getattr(record, id_key)
        if ident in seen:
            raise DataError(f"{path}: {label}: duplicate {id_key} (first at {container}[{seen[ident]}])")
        seen[ident] = i
        _check_participant(path, label, record.participant_id)
        out.append(record)
    return out


def load_eam_qa_file(path: str | Path) -> EamQaFile:
    path = Path(path)
    data = _read_json(path)
    if not isinstance(data, dict) or "questions" not in data:
        raise DataError(f"{path}: expected an object {{\"questions\": [...], \"metadata\": {{...}}}}")
    questions = _validate_items(path, data["questions"], EamQuestion, "questions", "question_id")
    metadata = data.get("metadata", {})
    if not isinstance(metadata, dict):
        raise DataError(f"{path}: metadata: expected a JSON object, got {type(metadata).__name__}")
    return EamQaFile(questions=questions, metadata=metadata)


def load_replay_file(path: str | Path) -> list[ReplayTask]:
    path = Path(path)
    return _validate_items(path, _read_json(path), ReplayTask, "tasks", "task_id")


def load_generalize_file(path: str | Path) -> list[GeneralizeTask]:
    path = Path(path)
    return _validate_items(path, _read_json(path), GeneralizeTask, "tasks", "task_id")


@dataclass
class ParticipantTasks:
    participant_id: str
    eam_qa: EamQaFile | None = None
    replay: list[ReplayTask] | None = None
    generalize: list[GeneralizeTask] | None = None


@dataclass
class BenchSuite:
    participants: dict[str, ParticipantTasks] = field(default_factory=dict)
    root: Path | None = None

    def questions(self) -> list[EamQuestion]:
        return [q for p in self.participants.values() if p.eam_qa for q in p.eam_qa.questions]

    def replay_tasks(self) -> list[ReplayTask]:
        return [t for p in self.participants.values() for t in (p.replay or [])]

    def generalize_tasks(self) -> list[GeneralizeTask]:
        return [t for p in self.participants.values() for t in (p.generalize or [])]


def normalize_participants(participants: list[str] | None) -> set[str] | None:
    if not participants:
        return None
    return {p.strip().upper() for p in participants if p.strip()}


def load_suite(root: str | Path | None = None, participants: list[str] | None = None) -> BenchSuite:
    """Load every task file under a release folder (default: the bundled calibration cohort)."""
    root = Path(root) if root else calibration_dir()
    if not root.is_dir():
        raise DataError(f"{root}: not a directory")
    folders = {"eam_qa": root / EAM_DIR, "replay": root / REPLAY_DIR, "generalize": root / GENERALIZE_DIR}
    if not any(f.is_dir() for f in folders.values()):
        raise DataError(
            f"{root}: not a MEMORA-Bench release: expected {EAM_DIR}/ and/or {REPLAY_DIR}/, {GENERALIZE_DIR}/"
        )
    wanted = normalize_participants(participants)
    readers = {"eam_qa": load_eam_qa_file, "replay": load_replay_file, "generalize": load_generalize_file}
    suite = BenchSuite(root=root)
    for kind, folder in folders.items():
        if not folder.is_dir():
            continue
        for path in sorted(folder.glob("*.json")):
            pid = path.stem.upper()
            if wanted is not None and pid not in wanted:
                continue
            entry = suite.participants.setdefault(pid, ParticipantTasks(participant_id=pid))
            setattr(entry, kind, readers[kind](path))
    suite.participants = dict(sorted(suite.participants.items()))
    if wanted is not None:
        missing = sorted(wanted - set(suite.participants))
        if missing:
            raise DataError(f"{root}: no task files for participant(s) {', '.join(missing)}")
    return suite


# ---------------------------------------------------------------------------------------------
# Writing (UTF-8, 2-space indent, trailing newline, as in the release)
# ---------------------------------------------------------------------------------------------

def write_json(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")


def write_suite(suite: BenchSuite, out: str | Path) -> list[Path]:
    out = Path(out)
    written = []
    for pid, entry in suite.participants.items():
        name = f"{pid.lower()}.json"
        if entry.eam_qa is not None:
            path = out / EAM_DIR / name
            write_json(path, {
                "questions": [q.model_dump(exclude_none=True) for q in entry.eam_qa.questions],
                "metadata": entry.eam_qa.metadata,
            })
            written.append(path)
        for kind, folder in (("replay", REPLAY_DIR), ("generalize", GENERALIZE_DIR)):
            tasks = getattr(entry, kind)
            if tasks is not None:
                path = out / folder / name
                write_json(path, [t.model_dump(exclude_none=True) for t in tasks])
                written.append(path)
    return written

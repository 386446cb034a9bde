"""Records of task-level memory (no I/O): a task (one stretch of steps serving one goal) and a
task pattern (how recurring tasks are done, one record per detector finding).

Both are written through the same collector as every other inferred record: a task as a
`Routine` row (source "task"), a recurring task's canonical stages as a `Routine` row (source
"task_routine"), a pattern as a `Preference` row whose subtype is its family. So
`get_routine_skill`, `get_preferences` and `search_patterns` return them with no new tool, and
any processor (rule or model) gets them: they are computed from the typed stores alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, NamedTuple

from pydantic import BaseModel, ConfigDict, Field

from memora_graph.consolidate.records import StepAction

Stage = Literal["setup", "main", "finish", "cleanup"]
TASK_ROUTINE_SOURCE = "task_routine"  # a recurring task's canonical stages, as a Routine row
TASK_PATTERN_SOURCE = "tasks"  # how tasks are done (every other family), as a Preference row
TASK_SOURCES = frozenset({TASK_ROUTINE_SOURCE, TASK_PATTERN_SOURCE})
FAMILIES = ("canonical", "order", "staging", "batch", "repetition", "setup", "carrier", "closure")
PREFERENCE_FAMILIES = FAMILIES[1:]  # every family but the canonical stages is written as a Preference row


class _Record(BaseModel):
    model_config = ConfigDict(extra="forbid")


class TaskStep(_Record):
    action: StepAction
    stage: Stage
    t: float
    segment: str
    text: str


class Task(_Record):
    id: str  # stable: participant + video + first segment
    video: str
    goal: str  # "wash up saucepan", "make coffee"
    family: str  # cleanup | cooking | prep | setup | store
    main_object: str
    t_start: float
    t_end: float
    steps: list[TaskStep]
    objects: list[str] = Field(default_factory=list)  # kinds, most handled first
    tools: list[str] = Field(default_factory=list)
    places: list[str] = Field(default_factory=list)  # place ids in the order first used
    segments: list[str] = Field(default_factory=list)
    entities: list[str] = Field(default_factory=list)

    def stage(self, name: str) -> list[TaskStep]:
        return [s for s in self.steps if s.stage == name]


class CompactAction(NamedTuple):
    """`StepAction` as a tuple: a batch run makes one per distinct step and shares it between the
    steps (a pydantic step per step was most of what task memory held: docs/build-memory.md)."""

    verb: str
    noun: str = ""
    place: str = ""
    instrument: str = ""

    def model_dump(self) -> dict:
        return self._asdict()  # StepAction.model_dump(): the same keys in the same order


class CompactStep(NamedTuple):
    """`TaskStep` as a tuple (the same fields, read the same way by the detectors)."""

    action: CompactAction
    stage: str
    t: float
    segment: str
    text: str


@dataclass(slots=True)
class CompactTask:
    """`Task` with its steps as tuples: what a batch consolidation holds for every task of a
    participant until the detectors and the writer have read them. The same fields as `Task`;
    `record()` is the `Task`."""

    id: str
    video: str
    goal: str
    family: str
    main_object: str
    t_start: float
    t_end: float
    steps: list[CompactStep]
    objects: list[str]
    tools: list[str]
    places: list[str]
    segments: list[str]
    entities: list[str]

    def stage(self, name: str) -> list[CompactStep]:
        return [s for s in self.steps if s.stage == name]

    @classmethod
    def of(cls, t: Task, share: dict | None = None) -> CompactTask:
        """A `Task` record as a compact task (`share`: as in `consolidate.tasks.make_task`)."""
        share = {} if share is None else share
        steps = []
        for s in t.steps:
            a = CompactAction(**s.action.model_dump())
            steps.append(CompactStep(share.setdefault(a, a), s.stage, s.t, s.segment, share.setdefault(s.text, s.text)))
        return cls(t.id, t.video, t.goal, t.family, t.main_object, t.t_start, t.t_end, steps, list(t.objects),
                   list(t.tools), list(t.places), list(t.segments), list(t.entities))

    def record(self) -> Task:
        return Task(id=self.id, video=self.video, goal=self.goal, family=self.family, main_object=self.main_object,
                    t_start=self.t_start, t_end=self.t_end,
                    steps=[TaskStep(action=StepAction(**s.action._asdict()), stage=s.stage, t=s.t, segment=s.segment,
                                    text=s.text) for s in self.steps],
                    objects=list(self.objects), tools=list(self.tools), places=list(self.places),
                    segments=list(self.segments), entities=list(self.entities))


class TaskPattern(_Record):
    family: str  # one of FAMILIES
    key: tuple[str, ...]  # what makes it unique within its family
    statement: str
    goal: str = ""  # the recurring task it is about ("" for a pattern over every task)
    objects: list[str] = Field(default_factory=list)
    actions: list[StepAction] = Field(default_factory=list)  # the steps it speaks about, in the order it states
    count: int = Field(ge=1)  # times it held
    total: int = Field(ge=1)  # times it could have held
    exceptions: list[str] = Field(default_factory=list)  # segment ids where it did not hold
    evidence: list[str] = Field(default_factory=list)  # segment ids where it held
    tasks: list[str] = Field(default_factory=list)
    videos: dict[str, int] = Field(default_factory=dict)
    detail: dict = Field(default_factory=dict)

    @property
    def confidence(self) -> float:
        return round(self.count / self.total, 3)

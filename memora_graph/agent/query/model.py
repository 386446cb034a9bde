"""The typed query: what can be asked of one person's memory, as one pydantic model.

    from memora_graph.agent.query import Query, recall
    q = Query(operation="count", subject={"verb": "open", "objects": ["fridge"]}, scope={"videos": ["P06_101"]})
    recall(view, "P06", q).count

A query is an operation on a subject, inside a scope, picked by a selector, optionally related
to an anchor event:

- operation  where | when | which_video | count | exists | list | next | previous | steps | state | duration
- subject    an action (verb class) on objects (noun classes or the person's own words), a place,
             a second object
- scope      all memory, some videos, a time window inside a video, before / after an event, the
             nth (or last) session
- selector   first | last | nth | usual (most frequent) | all
- relation   before | after | while | instead_of, with the anchor event it relates to

The natural-language parser (`query.parse`), the answerer (`query.answer`) and the `recall` tool
(library and MCP server) share this model; `Query.model_json_schema()` is the schema an agent
fills in. `why_not` says why a combination makes no sense (an answer then says so).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from memora_graph.limits import MAX_TEXT
from memora_graph.records import MAX_VIDEO_SECONDS

Operation = Literal["where", "when", "which_video", "count", "exists", "list", "next", "previous", "steps", "state",
                    "duration"]
Selector = Literal["first", "last", "nth", "usual", "all"]
Relation = Literal["before", "after", "while", "instead_of"]
OPERATIONS: tuple[str, ...] = Operation.__args__  # type: ignore[attr-defined]
SELECTORS: tuple[str, ...] = Selector.__args__  # type: ignore[attr-defined]
RELATIONS: tuple[str, ...] = Relation.__args__  # type: ignore[attr-defined]
MAX_QUESTION = MAX_TEXT  # characters: a longer question is refused (QuestionError); one cap for all free text
MAX_ITEMS = 32  # at most this many objects, videos or words in one list of a query
Word = Annotated[str, Field(max_length=MAX_TEXT)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Action(_Strict):
    """An action: a verb class and its objects. Objects are EPIC noun classes ('board:chopping') or
    the person's own words ('v60', 'chopping board'); either resolves against their vocabulary."""

    verb: str | None = Field(None, max_length=MAX_TEXT, description="Verb class or word ('open', 'take', 'put', 'wash'); none: any action "
                                               "with the objects.")
    objects: list[Word] = Field(default_factory=list, max_length=MAX_ITEMS, description="The objects, most important first (class or the "
                                                                 "person's word, e.g. 'fridge', 'chopping board').")
    words: list[Word] = Field(default_factory=list, max_length=MAX_ITEMS, description="The objects as the question worded them (filled by "
                                                               "the parser; an agent may leave it empty).")

    def empty(self) -> bool:
        return self.verb is None and not self.objects


class Subject(Action):
    place: str | None = Field(None, max_length=MAX_TEXT, description="A place the action happened at or went to ('drawer').")
    second: str | None = Field(None, max_length=MAX_TEXT, description="A second object ('the knife' in 'cut the onion with the knife').")
    source: bool = Field(False, description="where: the place it is taken from (not put).")
    goal: str = Field("", max_length=MAX_TEXT, description="steps: the goal in words ('make tea').")


class Scope(_Strict):
    videos: list[Word] = Field(default_factory=list, max_length=MAX_ITEMS, description="Only these videos (ids like 'P01_103'); empty: all.")
    start: float | None = Field(None, ge=0, le=MAX_VIDEO_SECONDS, description="Seconds into the video: the window's start.")
    end: float | None = Field(None, ge=0, le=MAX_VIDEO_SECONDS, description="Seconds into the video: the window's end ('at 01:00' is a "
                                                      "window ending there).")
    at: float | None = Field(None, ge=0, le=MAX_VIDEO_SECONDS, description="A moment, in seconds into the video: where / state / count read "
                                                     "up to it; list reads the log within 15 s of it.")
    after: Action | None = Field(None, description="Only what happened after this event (in the same video).")
    before: Action | None = Field(None, description="Only what happened before this event (in the same video).")
    session: int | None = Field(None, ge=-1, le=100_000, description="The nth session (video) of the person, 1-based; -1 the last.")

    def empty(self) -> bool:
        return not (self.videos or self.start is not None or self.end is not None or self.at is not None or self.after or self.before
                    or self.session is not None)


class Query(_Strict):
    """What is asked of one person's memory (see the module docstring)."""

    operation: Operation = Field(description="What the answer is: where (a place), when (a video and time), "
                                             "which_video, count, exists (yes/no), list (the actions), next / "
                                             "previous (the actions after / before the subject), steps (a routine), "
                                             "state (of objects at a time), duration (seconds).")
    subject: Subject = Field(default_factory=Subject, description="The action or objects asked about.")
    scope: Scope = Field(default_factory=Scope, description="Where in memory to look (default: all of it).")
    selector: Selector = Field("usual", description="Which occurrence: first, last, nth, usual (the most frequent), "
                                                    "all.")
    nth: int | None = Field(None, ge=1, le=100_000, description="selector nth: which occurrence (1-based).")
    relation: Relation | None = Field(None, description="How the answer relates to `anchor`: before, after, while "
                                                        "(during), instead_of (used in its place).")
    anchor: Action | None = Field(None, description="The event the relation is to ('put the pot').")
    unit: Literal["times", "videos"] = Field("times", description="count: occurrences or videos.")
    person: str | None = Field(None, max_length=MAX_TEXT, description="Whose memory the question names (none: the memory's owner).")
    world: bool = Field(False, description="The question asks about the world, not the person (general knowledge).")
    unknown: list[Word] = Field(default_factory=list, max_length=MAX_ITEMS, description="Words of the question no class or vocabulary knows.")
    text: str = Field("", max_length=MAX_TEXT, description="The question in words, when it came as words.")

    def why_not(self) -> str | None:
        """Why this combination makes no sense, or None."""
        op, sel = self.operation, self.selector
        if self.relation and self.anchor is None:
            return f"relation {self.relation!r} needs an anchor event"
        if self.anchor is not None and self.relation is None:
            return "an anchor event needs a relation (before, after, while, instead_of)"
        if sel == "nth" and self.nth is None:
            return "selector 'nth' needs nth"
        if op in ("state",) and self.relation in ("instead_of",):
            return "the state of an object has nothing 'instead of' it"
        if op == "steps" and self.subject.empty() and not self.subject.goal:
            return "steps need a goal or an action"
        if op in ("count", "exists", "duration") and sel in ("first", "last", "nth") and self.relation is None:
            return f"{op} covers every occurrence; '{sel}' picks one (ask 'when' or 'where' for it)"
        if self.scope.start is not None and self.scope.end is not None and self.scope.end < self.scope.start:
            return "the time window ends before it starts"
        if op in ("where", "when", "which_video", "count", "exists") and self.subject.empty() \
                and self.relation is None:
            return f"{op} needs something to ask about: an action or an object"
        if op == "duration" and self.subject.empty() and self.scope.empty():
            return "duration needs an action, an object or a scope (a video, a time window)"
        return None

    def brief(self) -> str:
        """The query in one line (for `--explain`)."""
        s = self.subject
        parts = [self.operation]
        what = " ".join(x for x in [s.verb or "", *(s.objects or [])] if x)
        if what:
            parts.append(f"subject={what}")
        if s.place:
            parts.append(f"place={s.place}")
        if s.source:
            parts.append("from")
        if not self.scope.empty():
            parts.append("scope=" + self.scope.model_dump_json(exclude_none=True, exclude_defaults=True))
        parts.append(f"selector={self.selector}" + (f"({self.nth})" if self.nth else ""))
        if self.relation:
            a = self.anchor
            parts.append(f"relation={self.relation}:{' '.join(x for x in [a.verb or '', *a.objects] if x)}" if a
                         else f"relation={self.relation}")
        if self.world:
            parts.append("world")
        return " ".join(parts)


# -- the typed answer ---------------------------------------------------------------------------------

class PlaceValue(BaseModel):
    place: str = Field(description="EPIC noun class of the place (e.g. 'drawer', 'board:chopping').")
    name: str = Field(description="The place in words.")
    video: str | None = Field(None, description="Video of the observation (last / first put).")
    time_seconds: float | None = Field(None, description="Seconds into that video.")
    count: int = Field(0, description="Observations of the object put (or taken) there.")
    share: float | None = Field(None, description="Share of all the object's placements that went there.")


class MomentValue(BaseModel):
    video: str
    time_seconds: float
    clock: str = Field(description="The time as MM:SS into the video.")


class ActionShare(BaseModel):
    verb: str = Field(description="EPIC verb class.")
    noun: str = Field(description="EPIC noun class ('' when none).")
    text: str
    count: int
    share: float = Field(description="Share of the observed cases.")


class RoutineStep(BaseModel):
    order: int
    verb: str
    noun: str
    text: str


class ObjectStateEvent(BaseModel):
    object: str
    state: str
    location: str
    video: str
    time_seconds: float
    event_id: str


class LogLine(BaseModel):
    video: str
    time_seconds: float
    text: str
    segment_id: str


class OpenAnswer(BaseModel):
    """A query's answer in the type asked, with its evidence and confidence."""

    question: str
    participant: str
    asked: str = Field(description="The query's operation: " + ", ".join(OPERATIONS) + ".")
    kind: str = Field(description="The answer's type: place, time, count, yesno, next, routine, state, activity "
                                  "(a log), actions (with shares), duration, or not_in_memory.")
    answer: str = Field(description="The answer in words.")
    in_memory: bool
    subject: dict[str, list[str]] = Field(default_factory=dict, description="The verb and noun classes asked about, "
                                          "and the person's words matched as said.")
    place: PlaceValue | None = None
    moment: MomentValue | None = None
    count: int | None = None
    yes: bool | None = None
    actions: list[ActionShare] = Field(default_factory=list)
    steps: list[RoutineStep] = Field(default_factory=list)
    states: list[ObjectStateEvent] = Field(default_factory=list)
    log: list[LogLine] = Field(default_factory=list)
    seconds: float | None = Field(None, description="duration: the time spent, in seconds.")
    reason: Literal["general_knowledge", "absent_subject", "invalid_query"] | None = Field(
        None, description="Why not in memory: general knowledge, a subject absent from this person's memory, or a "
                          "query that makes no sense (the detail says why).")
    widened: str = Field("", description="Set when the subject was read as its class because the person never "
                                         "names it so ('no wok in P22's words; read as its class, pan').")
    cut: str = Field("", description="Set when a list was cut: how many items there are and how to see the rest.")
    query: dict = Field(default_factory=dict, description="The typed query answered (its non-default fields).")
    detail: str = Field("", description="What the answer rests on, in words.")
    evidence: list[str] = Field(default_factory=list, description="Ids of the records behind the answer.")
    records: list[LogLine] = Field(default_factory=list, description="The narrated steps behind the answer (for a "
                                                                    "count, the records counted; at most 20).")
    support: int = Field(0, description="How many records support the answer.")
    confidence: float = Field(0.0, description="Probability that the answer is right (open_calibration.json).")
    features: dict[str, float] = Field(default_factory=dict, description="The evidence features the confidence reads.")




Answer = OpenAnswer

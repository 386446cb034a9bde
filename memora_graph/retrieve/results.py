"""Typed tool results: one pydantic model per record kind and per tool result.

A tool returns a result model (the envelope: tool, participant, arguments, its records). Every
record has `text()`, the one line a renderer prints and a text reader reads, and carries the
structured fields its store holds, so a reader that wants types reads fields, never sentences:
a preference's object and preferred location, a habit's trigger and next action, a routine's
ordered steps as (verb, noun, place), an activity's actions as (verb, noun), an object's state,
place and history. `records()` yields (list name, record) in rank order: what a reader takes as
evidence from the result.

JSON (`model_dump(mode="json")`) is what an agent sees; optional fields that are None are left
out, so a record shows only what its store holds.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, ClassVar, Generic, TypeVar

from pydantic import BaseModel, ConfigDict, Field, model_serializer


class Model(BaseModel):
    """Base of every result and record: optional fields listed in `_optional` are left out of the
    JSON when None, so the JSON says what is there and nothing else."""

    model_config = ConfigDict(extra="forbid")
    _optional: ClassVar[frozenset[str]] = frozenset()

    @model_serializer(mode="wrap")
    def _drop_absent(self, handler):
        data = handler(self)
        fields = type(self).model_fields
        for key in self._optional:
            for name in (key, fields[key].alias if key in fields else None):
                if name in data and data[name] is None:
                    del data[name]
        return data


class Record(Model):
    def text(self) -> str:
        """The record in one line of words."""
        return ""

    def from_video(self) -> str:
        """The video the record comes from ("" when it spans videos or has none)."""
        return ""


class Score(Model):
    """Why a record was returned: each signal's raw score and rank, and the fused score."""

    vector: float
    vector_rank: int | None = None
    keyword: float | None = None
    keyword_rank: int | None = None
    graph: float | None = None
    fused: float


class TimePoint(Model):
    video: str | None = None
    t: float | None = None


class Action(Model):
    """One action as (verb, noun) EPIC-KITCHENS class keys, with where it happened (or went) and
    what it was done with, when known."""

    _optional = frozenset({"place", "instrument"})
    verb: str
    noun: str = ""
    place: str | None = None
    instrument: str | None = None

    def text(self) -> str:
        return f"{self.verb} {self.noun}".strip() + (f" with {self.instrument}" if self.instrument else "") + \
            (f" at {self.place}" if self.place else "")


# -- entity memory ------------------------------------------------------------------------------

class SpatialInfo(Model):
    location: str
    place: str
    is_fixture: bool


class ObjectState(Model):
    current_state: str
    held_by: str | None = None
    status: str


class PlaceCount(Model):
    location: str
    place: str
    observations: int


class UsedWith(Model):
    entity_id: str
    name: str
    segments: int


class SeenTimes(Model):
    first: TimePoint
    last: TimePoint


class ObjectRecord(Record):
    """An object of entity memory: identity, attributes, current state and place."""

    _optional = frozenset({"duplicates"})
    object_id: str
    entity_id: str
    name: str
    kind: str
    category: str
    visual_properties: dict[str, str]
    spatial_info: SpatialInfo
    state: ObjectState
    places: list[PlaceCount]
    used_with: list[UsedWith]
    time_seen_seconds: SeenTimes
    n_observations: int | None = None
    similarity: float
    score: Score
    evidence: list[str]
    duplicates: list[str] | None = None

    def text(self) -> str:
        return self.name + (f": {self.state.current_state}" if self.state.current_state else "") + \
            (f" at {self.spatial_info.place or self.spatial_info.location}" if self.spatial_info.place or self.spatial_info.location else "")


class VisibleObject(Record):
    """An object as the state history has it at one moment (get_state_at_time)."""

    entity_id: str
    object_id: str | None = None
    name: str
    state: str
    location: str
    zone: str | None = None
    held_by: str | None = None
    relative_to: str | None = None
    relation: str | None = None
    since_seconds: float
    last_action: str | None = None
    event_id: str
    segment_id: str

    def text(self) -> str:
        return self.name + (f": {self.state}" if self.state else "") + (f" at {self.location}" if self.location else "")


class HistoryEntry(Record):
    """One observation of an object's state history (immutable StateEvent)."""

    event_id: str
    segment_id: str
    video: str
    turn_id: int
    time_seconds: float
    state: str
    location: str
    zone: str | None = None
    held_by: str | None = None
    relative_to: str | None = None
    relation: str | None = None
    action: str | None = None
    narration: str | None = None
    editor_op: str | None = None

    def text(self) -> str:
        return self.narration or f"{self.action or ''} -> {self.state} at {self.location}".strip()

    def from_video(self) -> str:
        return self.video


class LocationTransition(Model):
    video: str
    t: float
    from_location: str = Field(alias="from")
    to: str
    across_videos: bool
    segment_id: str
    event_id: str

    model_config = ConfigDict(extra="forbid", populate_by_name=True, serialize_by_alias=True)


class VideoHistory(Model):
    video: str
    observations: int
    first_t: float
    last_t: float
    states: list[str]
    locations: list[str]
    final_state: str
    final_location: str


class OtherMatch(Record):
    entity_id: str
    name: str
    status: str

    def text(self) -> str:
        return self.name


# -- activity memory ----------------------------------------------------------------------------

class TimeSpan(Model):
    start: float
    end: float


class ActionStepView(Model):
    """One narrated action of a segment's breakdown: `action` is the verb, `object` the noun."""

    t: str
    action: str
    object: str
    narration: str


class ActivityRecord(Record):
    """A 10 s segment of activity memory with what came before and after."""

    _optional = frozenset({"similarity", "score", "duplicates"})
    segment_id: str
    source_video: str
    turn_id: int
    time: TimeSpan
    summary: str
    detailed_narrative: str
    action_breakdown: list[ActionStepView]
    previous_action: str | None
    next_action: str | None
    scene_objects: list[str]
    environment: str
    similarity: float | None = None
    score: Score | None = None
    duplicates: list[str] | None = None
    evidence: list[str]

    def text(self) -> str:
        return self.summary

    def from_video(self) -> str:
        return self.source_video

    def actions(self) -> list[Action]:
        return [Action(verb=s.action, noun=s.object) for s in self.action_breakdown if s.action]


# -- environment memory -------------------------------------------------------------------------

class PlaceRecord(Record):
    _optional = frozenset({"duplicates"})
    place_id: str
    name: str
    zones: list[str]
    features: list[str]
    turns: int | None = None
    first_seen: TimePoint
    last_seen: TimePoint
    objects_here: list[str]
    similarity: float
    score: Score
    evidence: list[str]
    duplicates: list[str] | None = None

    def text(self) -> str:
        return self.name


# -- inferred knowledge -------------------------------------------------------------------------

class RoutineStepText(Model):
    action: str


class KeyObject(Model):
    object: str


class RoutineRecord(Record):
    """A routine skill or recurring action sequence: goal, ordered steps, key objects, episodes.
    `steps` holds the canonical steps as (verb, noun, place) where consolidation recorded them."""

    _optional = frozenset({"similarity", "score", "duplicates", "steps"})
    routine_id: str
    goal: str
    activity_type: str
    canonical_steps: list[RoutineStepText]
    steps: list[Action] | None = None
    key_objects: list[KeyObject]
    supporting_episodes: list[str]
    source_videos: list[str]
    count: int
    confidence: float
    source: str
    kind: str
    processor: str
    similarity: float | None = None
    score: Score | None = None
    duplicates: list[str] | None = None
    evidence: list[str]

    def text(self) -> str:
        if not self.goal:
            return ""
        return self.goal + (": " + "; ".join(s.action for s in self.canonical_steps) if self.canonical_steps else "")


PREFERENCE_FIELDS = ("object", "preferred_location", "place", "trigger", "next_action", "trigger_step", "next_step", "actions",
                     "use", "then", "alternatives", "trigger_count", "total")


class PreferenceRecord(Record):
    """A preference (storage, habit, workflow, tool, ...) with its structured fields: a storage
    preference's object and preferred location; a habit's trigger and next action; a workflow's
    use ("wash @ sink") and what follows ("put on drying rack"); the alternatives it beat."""

    _optional = frozenset({"score", "duplicates", *PREFERENCE_FIELDS})
    preference_id: str
    preference: str
    subtype: str
    keywords: list[str]
    objects: list[str]
    context: str
    object: str | None = None
    preferred_location: str | None = None
    place: str | None = None
    trigger: str | None = None
    next_action: str | None = None
    trigger_step: Action | None = None  # a habit's trigger and next action as (verb, noun, place) classes
    next_step: Action | None = None
    actions: list[Action] | None = None  # what a generated preference is about (a tool: verb, target, tool)
    use: str | None = None
    then: str | None = None
    alternatives: dict[str, int] | None = None
    trigger_count: int | None = None
    total: int | None = None
    evidence_summary: str
    confidence: float
    count: int
    supporting_episodes: list[str]
    source_videos: list[str]
    source: str
    processor: str
    similarity: float
    score: Score | None = None
    duplicates: list[str] | None = None
    evidence: list[str]

    def text(self) -> str:
        return self.preference


class PatternRecord(Record):
    """A consolidated pattern (a routine or a preference) in one line, as search_patterns lists it."""

    _optional = frozenset({"duplicates"})
    category: str
    pattern_id: str
    description: str
    source: str
    supporting_episodes: list[str]
    confidence: float
    count: int
    similarity: float | None = None
    score: Score | None = None
    evidence: list[str]
    duplicates: list[str] | None = None

    def text(self) -> str:
        return self.description


# -- results ------------------------------------------------------------------------------------

R = TypeVar("R", bound=Record)


class ToolResult(Model):
    """The envelope every tool result shares. Subclasses name their record lists in `_lists`."""

    _lists: ClassVar[tuple[str, ...]] = ()

    def records(self) -> Iterator[tuple[str, Record]]:
        """(list name, record) of every record a reader takes as evidence, list by list, each in
        rank order."""
        for name in self._lists:
            for rec in getattr(self, name) or []:
                yield name, rec

    def text(self) -> str:
        return "\n".join(r.text() for _, r in self.records() if r.text())

    def as_json(self) -> dict[str, Any]:
        return self.model_dump(mode="json")


class ToolErrorResult(ToolResult):
    """A call the tool could not answer; `error` says what would work."""

    error: str


class MemoraResult(ToolResult):
    _optional = frozenset({"notes"})
    tool: str
    participant: str
    arguments: dict[str, Any]


class SearchResult(MemoraResult):
    _optional = frozenset({"notes", "objects", "activities", "places", "patterns"})
    _lists = ("objects", "activities", "places", "patterns")
    routing: list[str]
    objects: list[ObjectRecord] | None = None
    activities: list[ActivityRecord] | None = None
    places: list[PlaceRecord] | None = None
    patterns: list[PatternRecord] | None = None
    notes: list[str] | None = None


class ListResult(MemoraResult, Generic[R]):
    """A tool's ranked records of one kind, under `results`."""

    _lists = ("results",)
    results: list[R]
    notes: list[str] | None = None


class ObjectsResult(ListResult[ObjectRecord]):
    pass


class ActivitiesResult(ListResult[ActivityRecord]):
    pass


class PlacesResult(ListResult[PlaceRecord]):
    pass


class PatternsResult(ListResult[PatternRecord]):
    pass


class RoutinesResult(MemoraResult):
    _optional = frozenset({"notes", "error"})
    _lists = ("routines",)
    routines: list[RoutineRecord]
    error: str | None = None
    notes: list[str] | None = None


class PreferencesResult(MemoraResult):
    _lists = ("preferences",)
    preferences: list[PreferenceRecord]
    notes: list[str] | None = None


class ObjectHistoryResult(MemoraResult):
    """One object's state history across videos (found), or what was not found (error)."""

    _optional = frozenset({"notes", "error", "object_id", "entity_id", "name", "match_type", "status", "current_state",
                           "current_location", "all_states_observed", "all_locations_observed", "videos",
                           "location_transitions", "state_history", "history_total", "history_shown", "first_seen",
                           "last_seen", "other_matches", "evidence"})
    _lists = ("state_history", "other_matches")
    found: bool
    error: str | None = None
    object_id: str | None = None
    entity_id: str | None = None
    name: str | None = None
    match_type: str | None = None
    status: str | None = None
    current_state: str | None = None
    current_location: str | None = None
    all_states_observed: list[str] | None = None
    all_locations_observed: list[str] | None = None
    videos: list[VideoHistory] | None = None
    location_transitions: list[LocationTransition] | None = None
    state_history: list[HistoryEntry] | None = None
    history_total: int | None = None
    history_shown: int | None = None
    first_seen: TimePoint | None = None
    last_seen: TimePoint | None = None
    other_matches: list[OtherMatch] | None = None
    evidence: list[str] | None = None
    notes: list[str] | None = None


class ObjectCount(Model):
    name: str
    kind: str
    segments: int


class VideoActivitiesResult(MemoraResult):
    """One video's activity log: its records in time order, and the objects handled most in it."""

    _lists = ("results",)
    video: str
    duration: float | None = None
    segments: int
    objects: list[ObjectCount]
    results: list[ActivityRecord]
    notes: list[str] | None = None


class StateAtTimeResult(MemoraResult):
    _lists = ("visible_objects",)
    segment_id: str | None
    current_activity: str | None
    environment: str | None
    visible_objects: list[VisibleObject]
    evidence: list[str]
    notes: list[str] | None = None

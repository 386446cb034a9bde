"""Records of offline consolidation and inferred-knowledge enrichment (no I/O).

Field names follow the reference implementation: the consolidation processor emits storage
preferences, organizational habits, workflow patterns and action sequences per completed
video, merged per participant; the enrichment processor derives routine skills and generated
preferences (with keywords and supporting evidence ids). An LLM processor returns the same
models, so validation (evidence ids must exist) is one code path for every processor.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

StorageContext = Literal["storage", "during_use", "after_use", "default"]


class _Record(BaseModel):
    model_config = ConfigDict(extra="forbid")


class StepAction(_Record):
    """One step as classes: the EPIC verb class key, the object kind, and where it went or happened."""

    verb: str
    noun: str = ""
    place: str = ""
    instrument: str = ""  # the object it is done with ("wash spoon with sponge")


class StoragePreference(_Record):
    object: str  # object kind ("spatula")
    object_name: str = ""  # the name a person would use ("wooden spatula")
    statement: str = ""
    preferred_location: str  # "drawer", "drying rack", "sink area"
    place: str = ""  # the location id the preferred location lies in
    context: StorageContext
    count: int = Field(ge=1)  # observations at the preferred location
    total: int = Field(ge=1)  # observations of the object in this context
    alternatives: dict[str, int] = Field(default_factory=dict)
    confidence: float = Field(ge=0, le=1)
    supporting_episodes: list[str] = Field(default_factory=list)  # segment ids
    entities: list[str] = Field(default_factory=list)
    videos: dict[str, int] = Field(default_factory=dict)  # video -> observations


class OrganizationalHabit(_Record):
    trigger: str  # "wash bowl"
    next_action: str  # "put bowl on drying rack"
    trigger_step: StepAction | None = None  # the same two as classes
    next_step: StepAction | None = None
    habit: str = ""  # the statement
    count: int = Field(ge=1)  # times next_action followed trigger
    trigger_count: int = Field(ge=1)
    objects_involved: list[str] = Field(default_factory=list)
    confidence: float = Field(ge=0, le=1)
    supporting_episodes: list[str] = Field(default_factory=list)
    entities: list[str] = Field(default_factory=list)
    videos: dict[str, int] = Field(default_factory=dict)


class WorkflowPattern(_Record):
    pattern: str
    category: str  # object category the flow applies to ("crockery")
    use: str  # "wash @ sink area"
    then: str  # "put on drying rack"
    objects: list[str] = Field(default_factory=list)
    count: int = Field(ge=1)
    confidence: float = Field(ge=0, le=1)
    supporting_episodes: list[str] = Field(default_factory=list)
    entities: list[str] = Field(default_factory=list)
    videos: dict[str, int] = Field(default_factory=dict)


class ActionSequence(_Record):
    title: str
    steps: list[str]  # "take sponge", "wash bowl", ...
    actions: list[StepAction] = Field(default_factory=list)  # the same steps as classes (rule processor)
    activity_type: str
    key_objects: list[str] = Field(default_factory=list)
    count: int = Field(ge=1)  # occurrences
    confidence: float = Field(ge=0, le=1)
    supporting_episodes: list[str] = Field(default_factory=list)  # first segment of each occurrence
    segments: list[str] = Field(default_factory=list)  # every segment an occurrence spans
    entities: list[str] = Field(default_factory=list)
    videos: dict[str, int] = Field(default_factory=dict)


class VideoConsolidation(_Record):
    """The offline consolidation summary of one completed video."""

    video: str
    storage_preferences: list[StoragePreference] = Field(default_factory=list)
    organizational_habits: list[OrganizationalHabit] = Field(default_factory=list)
    workflow_patterns: list[WorkflowPattern] = Field(default_factory=list)
    action_sequences: list[ActionSequence] = Field(default_factory=list)


class Consolidation(_Record):
    """Participant-level consolidation: what repeats across the completed videos."""

    participant: str
    videos: list[str] = Field(default_factory=list)
    storage_preferences: list[StoragePreference] = Field(default_factory=list)
    organizational_habits: list[OrganizationalHabit] = Field(default_factory=list)
    workflow_patterns: list[WorkflowPattern] = Field(default_factory=list)
    action_sequences: list[ActionSequence] = Field(default_factory=list)


class Episode(_Record):
    video: str
    t_start: float
    t_end: float
    segments: list[str]


class RoutineSkill(_Record):
    goal: str
    activity_type: str
    canonical_steps: list[str]
    actions: list[StepAction] = Field(default_factory=list)  # the canonical steps as classes (rule processor)
    key_objects: list[str] = Field(default_factory=list)
    supporting_episodes: list[str] = Field(default_factory=list)  # first segment of each episode
    segments: list[str] = Field(default_factory=list)  # every segment the episodes span
    episodes: list[Episode] = Field(default_factory=list)
    count: int = Field(ge=1)  # episodes
    confidence: float = Field(ge=0, le=1)
    entities: list[str] = Field(default_factory=list)
    videos: dict[str, int] = Field(default_factory=dict)


class GeneratedPreference(_Record):
    subtype: str  # "tool" (which instrument for which action), open to an LLM processor's subtypes
    preference: str  # the statement
    keywords: list[str] = Field(default_factory=list)
    objects: list[str] = Field(default_factory=list)
    context: str = ""
    count: int = Field(ge=1)
    confidence: float = Field(ge=0, le=1)
    evidence_summary: str = ""
    supporting_evidence_ids: list[str] = Field(default_factory=list)  # segment ids
    entities: list[str] = Field(default_factory=list)
    alternatives: dict[str, int] = Field(default_factory=dict)
    videos: dict[str, int] = Field(default_factory=dict)
    actions: list[StepAction] = Field(default_factory=list)  # what it is about as classes (a tool: verb, target, tool)


class Enrichment(_Record):
    participant: str
    routine_skills: list[RoutineSkill] = Field(default_factory=list)
    generated_preferences: list[GeneratedPreference] = Field(default_factory=list)

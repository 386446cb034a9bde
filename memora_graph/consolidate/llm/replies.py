"""The model reply contract: the pydantic models a consolidation or enrichment reply is validated
with, lenient about what is not worth a repair turn (a number for a text, a percentage for a
confidence, "S1, S4" for a list of references)."""

from __future__ import annotations

import re
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field


def _text(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return str(value)
    return value.strip() if isinstance(value, str) else value


def _texts(value: Any) -> Any:
    if value is None:
        return []
    if isinstance(value, str):
        return [value] if value.strip() else []
    if isinstance(value, list):
        return [v for v in (_text(v) for v in value) if v != ""]
    return value


def _confidence(value: Any) -> Any:
    if value is None:
        return 0.5
    if isinstance(value, str):
        try:
            value = float(value.strip().rstrip("%"))
        except ValueError:
            return value
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = float(value)
        if 1 < value <= 100:  # a percentage
            value /= 100
        return min(max(value, 0.0), 1.0)
    return value


_SPLIT = re.compile(r"[,;\s]+")


def _refs(value: Any) -> Any:
    """Evidence references as strings: "S3", 3, "[S3]", "S1, S4" and real ids all pass."""
    if value is None:
        return []
    if isinstance(value, (str, int)) and not isinstance(value, bool):
        value = [value]
    if isinstance(value, list):
        out = []
        for v in value:
            if v is None or isinstance(v, bool):
                continue
            out += [p for p in _SPLIT.split(str(v).strip()) if p]
        return out
    return value


Text = Annotated[str, BeforeValidator(_text)]
Texts = Annotated[list[str], BeforeValidator(_texts)]
Confidence = Annotated[float, BeforeValidator(_confidence), Field(ge=0, le=1)]
Refs = Annotated[list[str], BeforeValidator(_refs)]


class _Reply(BaseModel):
    model_config = ConfigDict(extra="ignore")


class StorageItem(_Reply):
    object: Text = Field(min_length=1, description="the object, as named in the evidence")
    preferred_location: Text = Field(min_length=1, description="where it is kept or put")
    context: Text = Field("default", description="storage | during_use | after_use | default")
    confidence: Confidence = 0.5
    evidence: Text = ""
    supporting_episodes: Refs = Field(default_factory=list, description="evidence handles")


class HabitItem(_Reply):
    habit: Text = Field(min_length=1, description="the statement, e.g. 'After washing a bowl, puts it on the rack'")
    trigger: Text = ""
    next_action: Text = ""
    objects_involved: Texts = Field(default_factory=list)
    confidence: Confidence = 0.5
    supporting_episodes: Refs = Field(default_factory=list)


class WorkflowItem(_Reply):
    pattern: Text = Field(min_length=1, description="the statement")
    category: Text = Field("", description="the kind of object the flow applies to, e.g. crockery")
    use: Text = Field("", description="what is done with them and where, e.g. 'wash @ sink area'")
    then: Text = Field("", description="where they go next, e.g. 'put on drying rack'")
    objects: Texts = Field(default_factory=list)
    confidence: Confidence = 0.5
    supporting_episodes: Refs = Field(default_factory=list)


class ProcedureItem(_Reply):
    pattern_name: Text = ""
    goal: Text = ""
    activity_type: Text = ""
    key_objects: Texts = Field(default_factory=list)
    key_steps: Texts = Field(min_length=1, description="the steps in order, short imperative phrases")
    confidence: Confidence = 0.5
    supporting_episodes: Refs = Field(default_factory=list)


class ConsolidationReply(_Reply):
    """What a consolidation step answers, per video and across videos."""

    storage_preferences: list[StorageItem]
    organizational_habits: list[HabitItem]
    workflow_patterns: list[WorkflowItem]
    action_sequences: list[ProcedureItem]


class SkillItem(_Reply):
    goal: Text = Field(min_length=1)
    activity_type: Text = ""
    canonical_steps: Texts = Field(min_length=1)
    key_objects: Texts = Field(default_factory=list)
    supporting_evidence_ids: Refs = Field(default_factory=list)
    confidence: Confidence = 0.5


class SkillsReply(_Reply):
    routine_skills: list[SkillItem]


class PreferenceItem(_Reply):
    subtype: Text = "other"
    preference: Text = Field(min_length=1, description="the statement")
    keywords: Texts = Field(default_factory=list)
    objects: Texts = Field(default_factory=list)
    context: Text = ""
    confidence: Confidence = 0.5
    evidence_summary: Text = ""
    supporting_evidence_ids: Refs = Field(default_factory=list)


class PreferencesReply(_Reply):
    generated_preferences: list[PreferenceItem]

"""Pydantic records that flow between the stages: perceive -> form -> consolidate -> retrieve.

No I/O here. Field names follow the paper's layered record (environment, activity_narrative,
object_registry) and the reference implementation's.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

SPATIAL_RELATIONS = (
    "LEFT_OF", "RIGHT_OF", "ABOVE", "BELOW", "BEHIND", "IN_FRONT_OF", "ADJACENT_TO", "INSIDE", "ON_TOP_OF",
)
EditKind = Literal["ADD", "UPDATE", "DELETE", "NOOP"]


MAX_VIDEO_SECONDS = 24 * 3600.0  # the stated range of a time in a video (perceive/bounds.py)
_SECONDS = dict(ge=0, le=MAX_VIDEO_SECONDS + 10.0, allow_inf_nan=False)  # a last turn may end 10 s past it


class _Record(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Zone(_Record):
    anchor: str
    position: str = ""
    contents: list[str] = Field(default_factory=list)
    description: str = ""


class SpatialRelation(_Record):
    subject: str
    relation: str
    object: str

    @field_validator("relation")
    @classmethod
    def _known(cls, v: str) -> str:
        if v not in SPATIAL_RELATIONS:
            raise ValueError(f"relation must be one of {', '.join(SPATIAL_RELATIONS)}")
        return v

    def text(self) -> str:
        return f"{self.subject} {self.relation} {self.object}"


class EnvironmentLayer(_Record):
    layout_description: str = ""
    location_id: str = "kitchen_general"  # the place the person is mostly at in this turn
    places: list[str] = Field(default_factory=list)  # every location id seen in the turn
    zones: dict[str, Zone] = Field(default_factory=dict)
    spatial_relations: list[SpatialRelation] = Field(default_factory=list)
    features: list[str] = Field(default_factory=list)


class ActionStep(_Record):
    timestamp: float = Field(ge=0, le=10, description="seconds from the start of the turn")
    end: float = Field(description="seconds from the start of the turn; may run past 10", **_SECONDS)
    action: str  # verb
    object: str = ""
    narration: str = ""
    narration_id: str = ""
    hand: str = ""
    manner: str = ""
    direction: str = ""


class ActivityLayer(_Record):
    summary: str = ""
    detailed_narrative: str = ""
    action_breakdown: list[ActionStep] = Field(default_factory=list)
    concurrent_actions: list[str] = Field(default_factory=list)


class VisualProperties(_Record):
    color: str = ""
    material: str = ""
    size: str = ""
    shape: str = ""
    condition: str = ""
    quantity: str = ""


class ObjectObservation(_Record):
    object_id: str  # lowercase_with_underscores, reused across turns
    name: str
    kind: str = ""  # the normalized name without attributes ("spoon" for a wooden spoon)
    category: str = ""
    visual_properties: VisualProperties = Field(default_factory=VisualProperties)
    location: str = "kitchen_general"  # a location id
    zone: str = ""
    relative_to: str = ""
    relation: str = ""
    state: str = "observed"
    held_by: str | None = None
    is_fixture: bool = False
    t_rel: float = Field(0.0, ge=0, le=10)
    action: str = ""
    narration: str = ""
    narration_id: str = ""

    def model_post_init(self, _context) -> None:
        if not self.kind:
            self.kind = self.object_id

    def attributes(self) -> dict[str, str]:
        return {k: v for k, v in self.visual_properties.model_dump().items() if v}


class LayeredSegment(_Record):
    """z_t: one 10 s turn of one video, as the perception processor sees it."""

    participant_id: str
    video_id: str
    turn_id: int = Field(ge=0)
    t_start: float = Field(**_SECONDS)
    t_end: float = Field(**_SECONDS)
    environment: EnvironmentLayer = Field(default_factory=EnvironmentLayer)
    activity: ActivityLayer = Field(default_factory=ActivityLayer)
    objects: list[ObjectObservation] = Field(default_factory=list)
    working_summary: str = ""  # c_{t-1}: the bounded summary carried in from earlier turns

    @property
    def segment_id(self) -> str:
        return segment_id(self.video_id, self.turn_id)


def segment_id(video_id: str, turn_id: int) -> str:
    return f"{video_id}#t{turn_id:04d}"


class EditOp(_Record):
    """One editor decision, stored with its reason."""

    op: EditKind
    entity_id: str
    reason: str
    changes: dict[str, str] = Field(default_factory=dict)
    merged_into: str | None = None  # DELETE of a duplicate identification

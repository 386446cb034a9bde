"""The perception processor phi for video: a 10 s clip -> a layered segment record, by a VLM.

z_t = phi(v_t, c_{t-1}): the model sees the clip's frames (and its audio, for audio-capable
models such as Qwen2.5-Omni) plus a bounded text summary of the earlier turns of the same
video and the object ids already in use, and answers one JSON record (environment, activity
narrative, object registry) following the paper's perception prompt contract. The reply is
validated against `PerceptionReply` by the backend (one repair turn), then normalized into a
`LayeredSegment`: ids slugged and reused, locations mapped to the stable location ids that
environment memory merges on, trajectories expanded evenly across the clip.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

from memora_graph.llm.backends import (
    Backend, ModelReplyError, ModelServerError, ModelUnavailableError, audio_part, image_part, text_part,
)
from memora_graph.perceive.narration import slug
from memora_graph.perceive.video import VideoClip
from memora_graph.perceive.vocab import COLORS, DEFAULT_PLACE, MATERIALS, PLACE_NAMES, PLACE_NOUNS, SIZES
from memora_graph.records import (
    SPATIAL_RELATIONS, ActionStep, ActivityLayer, EnvironmentLayer, LayeredSegment, ObjectObservation,
    SpatialRelation, VisualProperties, Zone,
)

PROMPT_VERSION = "perception-v1"
SUMMARY_LIMIT = 600  # characters of c_{t-1}
KNOWN_IDS_LIMIT = 40  # object ids offered for reuse
RECENT_TURNS = 4
LOCATION_IDS = tuple(PLACE_NAMES)
IDENTITY_ATTRS = ("color", "material", "size")
OFFLINE_MESSAGE = (
    "Building memory from video needs a vision-language model for the perception step, and the "
    "'offline' backend has none (it only builds from action annotations). Serve a vision model with "
    "an OpenAI-compatible server, e.g. `vllm serve Qwen/Qwen2.5-VL-7B-Instruct`, then run: "
    "memora build BANK --video FILE_OR_DIR --participant P01 --backend openai "
    "--base-url http://127.0.0.1:8000/v1 --perception-model Qwen/Qwen2.5-VL-7B-Instruct "
    "(Qwen/Qwen2.5-Omni-7B also takes the audio track: add --audio)."
)

# -- the reply contract -------------------------------------------------------------------------


def _text(value: Any) -> Any:
    """Models write null or numbers where a string is asked for; neither is worth a repair turn."""
    if value is None:
        return ""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return str(value)
    return value


Text = Annotated[str, BeforeValidator(_text)]
Seconds = Annotated[float, Field(ge=0, le=10, description="seconds from the start of this clip, in [0, 10]")]


class _Reply(BaseModel):
    model_config = ConfigDict(extra="ignore")


class ZoneReply(_Reply):
    anchor: Text = ""
    position: Text = ""
    contents: list[Text] = Field(default_factory=list)
    description: Text = ""


class EnvironmentReply(_Reply):
    layout_description: Text = ""
    location_id: Text = Field(DEFAULT_PLACE, description="where the camera wearer mostly is; one of the location ids")
    zones: dict[str, ZoneReply] = Field(default_factory=dict)
    spatial_relations: list[Text] = Field(default_factory=list, description='"A REL B", REL one of ' + ", ".join(SPATIAL_RELATIONS))
    features: list[Text] = Field(default_factory=list)
    lighting: Text = ""
    ambient: Text = ""


class StepReply(_Reply):
    timestamp: Seconds
    action: Text = Field(min_length=1)
    object: Text = ""
    hand: Text = ""
    manner: Text = ""
    direction: Text = ""


class ActivityReply(_Reply):
    summary: Text = Field(min_length=1)
    detailed_narrative: Text = ""
    action_breakdown: list[StepReply] = Field(default_factory=list)
    concurrent_actions: list[Text] = Field(default_factory=list)


class VisualReply(_Reply):
    color: Text = ""
    material: Text = ""
    size: Text = ""
    shape: Text = ""
    condition: Text = ""
    quantity: Text = ""


class SpatialReply(_Reply):
    location: Text = DEFAULT_PLACE
    zone: Text = ""
    orientation: Text = ""
    relative_to: Text = ""
    movement_trajectory: str | None = None


class StateReply(_Reply):
    current_state: Text = "observed"
    held_by: str | None = None
    grip_type: str | None = None


class ObjectReply(_Reply):
    name: Text = ""
    first_seen: Seconds = 0.0
    is_fixture: bool = False
    visual_properties: VisualReply = Field(default_factory=VisualReply)
    spatial_info: SpatialReply = Field(default_factory=SpatialReply)
    state: StateReply = Field(default_factory=StateReply)


class PerceptionReply(_Reply):
    """What the perception model must answer for one clip (the paper's layered record)."""

    environment: EnvironmentReply
    activity_narrative: ActivityReply
    object_registry: dict[str, ObjectReply] = Field(default_factory=dict)
    verbalised_audio: Text = ""


SYSTEM_PROMPT = f"""You are the perception processor of a personal kitchen memory (prompt {PROMPT_VERSION}).
You watch one short clip from a head-mounted (egocentric) camera and describe what is visible.
Rules:
- Timestamps are relative: seconds from the start of THIS clip, in [0, 10].
- Reuse an object identifier from earlier turns when you see the same object. New identifiers are
  lowercase_with_underscores (red_mug, cutting_board); number look-alike instances (plate_1, plate_2).
- Locations are location ids: {", ".join(LOCATION_IDS)}.
- Fixed objects (sink, hob, fridge, cupboard, drawer) have is_fixture true and held_by null.
- Describe only what you see (and hear, when audio is given); do not guess hidden objects.
Answer with one JSON object:
{{"environment": {{"layout_description": str, "location_id": location id,
   "zones": {{zone_name: {{"anchor": object id, "position": location id, "contents": [object ids], "description": str}}}},
   "spatial_relations": ["A REL B" with REL one of {", ".join(SPATIAL_RELATIONS)}], "features": [str]}},
 "activity_narrative": {{"summary": one sentence, "detailed_narrative": str,
   "action_breakdown": [{{"timestamp": seconds, "action": verb, "object": object id, "hand": str, "manner": str, "direction": str}}],
   "concurrent_actions": [str]}},
 "object_registry": {{object_id: {{"name": str, "first_seen": seconds, "is_fixture": bool,
   "visual_properties": {{"color", "material", "size", "shape", "condition", "quantity"}},
   "spatial_info": {{"location": location id, "zone": str, "orientation": str, "relative_to": object id,
                    "movement_trajectory": "location -> location" or null}},
   "state": {{"current_state": str, "held_by": "left hand" | "right hand" | "both hands" | null, "grip_type": str or null}}}}}},
 "verbalised_audio": what is said or heard ("" without audio)}}"""


# -- normalization ------------------------------------------------------------------------------

_LOCATION_WORDS: list[tuple[str, str]] = sorted(
    [(key.split(":")[0], loc) for key, (loc, _) in PLACE_NOUNS.items() if loc != DEFAULT_PLACE]
    + [("stove", "stove_area"), ("cooker", "stove_area"), ("refrigerator", "fridge_area"),
       ("counter", "counter_area"), ("countertop", "counter_area"), ("worktop", "counter_area"),
       ("cabinet", "cabinet_area"), ("pantry", "cabinet_area"), ("table", "table_area"),
       ("trash", "bin_area"), ("garbage", "bin_area"), ("dish_rack", "sink_area"), ("basin", "sink_area")],
    key=lambda kv: -len(kv[0]),
)
_REL_RE = re.compile(r"^(.+?)\s+(" + "|".join(r.replace("_", "[ _]") for r in SPATIAL_RELATIONS) + r")\s+(.+)$", re.IGNORECASE)
_NUMBERED = re.compile(r"^(.*?)_?(\d+)$")
_TRAJECTORY_SPLIT = re.compile(r"\s*(?:->|→|=>|\bto\b|,|;)\s*")
_ADJECTIVES = COLORS | MATERIALS | SIZES
_NOBODY = {"", "none", "null", "nobody", "no one", "no", "n/a", "nothing"}


def normalize_location(text: str | None, default: str = DEFAULT_PLACE) -> str:
    """A free-text place ('left of the sink', 'Fridge') -> a stable location id ('sink_area')."""
    s = slug(text or "")
    if s in PLACE_NAMES:
        return s
    words = set(s.split("_"))
    for word, loc in _LOCATION_WORDS:
        if word in words or (len(word) > 4 and word in s):
            return loc
    return default


def object_kind(object_id: str) -> str:
    """The id without adjectives: 'red_mug' -> 'mug'. Numbers stay: plate_1 and plate_2 are
    look-alikes the perception model told apart, and the editor must not fold them together."""
    words = [w for w in object_id.split("_") if w and w not in _ADJECTIVES]
    return "_".join(words) or object_id


def _relation(text: str) -> SpatialRelation | None:
    m = _REL_RE.match(text.strip())
    if not m:
        return None
    return SpatialRelation(subject=slug(m.group(1)), relation=m.group(2).upper().replace(" ", "_"), object=slug(m.group(3)))


def _collapse_numbered(registry: dict[str, ObjectReply]) -> dict[str, ObjectReply]:
    """Ids slugged; more than 4 numbered variants of one base (cup_1 .. cup_6) become one object."""
    slugged: dict[str, ObjectReply] = {}
    for key, obj in registry.items():
        slugged.setdefault(slug(key), obj)
    variants: dict[str, list[str]] = {}
    for oid in slugged:
        m = _NUMBERED.match(oid)
        if m and m.group(1):
            variants.setdefault(m.group(1), []).append(oid)
    out: dict[str, ObjectReply] = {}
    for oid, obj in slugged.items():
        m = _NUMBERED.match(oid)
        base = m.group(1) if m and m.group(1) else None
        out.setdefault(base if base and len(variants.get(base, [])) > 4 else oid, obj)
    return out


def _stops(trajectory: str | None) -> list[str]:
    if not trajectory:
        return []
    stops = [normalize_location(part) for part in _TRAJECTORY_SPLIT.split(trajectory) if part.strip()]
    return [s for i, s in enumerate(stops) if i == 0 or s != stops[i - 1]]


def to_segment(reply: PerceptionReply, clip: VideoClip, participant: str, working_summary: str = "") -> LayeredSegment:
    """Map a validated reply onto the layered record; timestamps are clamped to the clip."""
    length = max(clip.seconds, 0.0)

    def clamp(t: float) -> float:
        return round(min(max(t, 0.0), length), 2)

    act = reply.activity_narrative
    steps_sorted = sorted(act.action_breakdown, key=lambda s: s.timestamp)
    steps = []
    for i, s in enumerate(steps_sorted):
        t = clamp(s.timestamp)
        end = clamp(steps_sorted[i + 1].timestamp) if i + 1 < len(steps_sorted) else round(length, 2)
        obj = slug(s.object) if s.object else ""
        text = " ".join(x for x in (s.action, s.object.replace("_", " ")) if x) + (f" ({s.manner})" if s.manner else "")
        steps.append(ActionStep(timestamp=t, end=max(end, t), action=s.action.lower(), object=obj, narration=text,
                                hand=s.hand, manner=s.manner, direction=s.direction))
    step_for = {}
    for st in steps:
        step_for.setdefault(st.object, st)

    objects: list[ObjectObservation] = []
    for oid, obj in _collapse_numbered(reply.object_registry).items():
        # Identity attributes only: the entity record keeps colour, material and size.
        vp = {k: (getattr(obj.visual_properties, k) or "").strip().lower() for k in IDENTITY_ATTRS}
        fixture = obj.is_fixture
        sp = obj.spatial_info
        final_loc = normalize_location(sp.location)
        stops = [] if fixture else _stops(sp.movement_trajectory)
        if stops and stops[-1] != final_loc:
            stops.append(final_loc)
        step = step_for.get(oid)
        action = step.action if step else ""
        narration = step.narration if step else f"seen: {obj.name or oid.replace('_', ' ')}"
        base = dict(
            object_id=oid, name=(obj.name or oid.replace("_", " ")).strip().lower(), kind=object_kind(oid),
            visual_properties=VisualProperties(**vp), zone=slug(sp.zone) if sp.zone else "",
            relative_to=slug(sp.relative_to) if sp.relative_to else "", is_fixture=fixture,
        )
        t0 = clamp(obj.first_seen)
        held = None if fixture or (obj.state.held_by or "").strip().lower() in _NOBODY else obj.state.held_by.strip()
        state = (obj.state.current_state or "observed").strip().lower()
        if len(stops) < 2:
            objects.append(ObjectObservation(**base, location=final_loc, state=state, held_by=held, t_rel=t0,
                                             action=action, narration=narration))
            continue
        # A trajectory is expanded evenly across the rest of the clip: one observation per stop.
        span = max(length - t0, 0.0)
        for k, loc in enumerate(stops):
            last = k == len(stops) - 1
            moved = f"moved from {stops[k - 1]} to {loc}" if k else f"at {loc}"
            objects.append(ObjectObservation(
                **base, location=loc, state=state if last else "observed", held_by=held if last else None,
                t_rel=clamp(t0 + span * k / len(stops)), action=(action or "move") if last else ("move" if k else ""),
                narration=narration if last and step else moved,
            ))

    env = reply.environment
    location = normalize_location(env.location_id)
    zones = {}
    for name, z in env.zones.items():
        zname = slug(name)
        zones[zname] = Zone(anchor=slug(z.anchor) if z.anchor else zname,
                            position=normalize_location(z.position or z.anchor or name, location),
                            contents=[slug(c) for c in z.contents if c], description=z.description)
    relations = [r for r in (_relation(t) for t in env.spatial_relations) if r is not None]
    places = list(dict.fromkeys([location, *(z.position for z in zones.values()), *(o.location for o in objects)]))
    narrative = act.detailed_narrative
    if reply.verbalised_audio.strip():
        narrative = (narrative + " " if narrative else "") + f"Audio: {reply.verbalised_audio.strip()}"
    features = list(dict.fromkeys([*(f for f in env.features if f), *(x for x in (env.lighting, env.ambient) if x)]))
    return LayeredSegment(
        participant_id=participant, video_id=clip.video_id, turn_id=clip.turn_id, t_start=clip.t_start,
        t_end=clip.t_end,
        environment=EnvironmentLayer(layout_description=env.layout_description, location_id=location, places=places,
                                     zones=zones, spatial_relations=relations, features=features),
        activity=ActivityLayer(summary=act.summary.strip(), detailed_narrative=narrative, action_breakdown=steps,
                               concurrent_actions=act.concurrent_actions),
        objects=objects, working_summary=working_summary,
    )


# -- c_{t-1}: the bounded working summary -------------------------------------------------------


@dataclass
class PerceptionContext:
    """What is carried from turn to turn of one video: recent summaries, the place, the objects
    in hand and the ids in use (for reuse). Never frames: nothing visual crosses turns."""

    limit: int = SUMMARY_LIMIT
    recent: list[str] = field(default_factory=list)
    place: str = ""
    held: list[str] = field(default_factory=list)
    known: dict[str, str] = field(default_factory=dict)  # object id -> "name, state at location"; recent last

    def summary(self) -> str:
        if not self.recent and not self.place:
            return ""
        parts = ["Earlier: " + " | ".join(self.recent[-RECENT_TURNS:])] if self.recent else []
        if self.place:
            parts.append(f"now at the {PLACE_NAMES.get(self.place, self.place)}")
        if self.held:
            parts.append("holding " + ", ".join(self.held))
        text = "; ".join(parts)
        return text if len(text) <= self.limit else "..." + text[-(self.limit - 3):]

    def known_ids(self) -> list[str]:
        return list(self.known)[-KNOWN_IDS_LIMIT:]

    def update(self, seg: LayeredSegment) -> None:
        self.recent.append(f"[{seg.t_start:.0f}-{seg.t_end:.0f}s] {seg.activity.summary[:120]}")
        self.recent = self.recent[-RECENT_TURNS:]
        self.place = seg.environment.location_id
        self.held = list(dict.fromkeys(o.object_id for o in seg.objects if o.held_by))
        for o in seg.objects:
            self.known.pop(o.object_id, None)
            self.known[o.object_id] = f"{o.name}, {o.state} at {o.location}"
        while len(self.known) > 4 * KNOWN_IDS_LIMIT:
            self.known.pop(next(iter(self.known)))


# -- the processor ------------------------------------------------------------------------------


@dataclass
class PerceivedClip:
    clip: VideoClip
    segment: LayeredSegment | None  # None when the model failed after its repair turn
    error: str | None = None


def wants_audio(model: str | None) -> bool:
    """Audio on for audio-capable perception models (Qwen2.5-Omni), off otherwise."""
    return bool(model) and any(k in model.lower() for k in ("omni", "audio"))


class VLMPerception:
    """phi for video through any chat backend that can see images."""

    role = "perception"

    def __init__(self, backend: Backend, participant: str, *, audio: bool | None = None,
                 summary_limit: int = SUMMARY_LIMIT):
        if not backend.supports(self.role):
            raise ModelUnavailableError(OFFLINE_MESSAGE)
        self.backend = backend
        self.participant = participant
        self.audio = wants_audio(backend.model) if audio is None else audio
        self.summary_limit = summary_limit

    def messages(self, clip: VideoClip, ctx: PerceptionContext) -> list[dict[str, Any]]:
        times = ", ".join(f"{f.t_rel:g}" for f in clip.frames)
        with_audio = self.audio and clip.audio_wav is not None
        known = ctx.known_ids()
        lines = [
            f"Turn {clip.turn_id} of video {clip.video_id} ({self.participant}): the clip from {clip.t_start:g} s "
            f"to {clip.t_end:g} s of the video, {clip.seconds:g} s long.",
            f"{len(clip.frames)} frames follow, in order, at relative times {times} s."
            + (" The clip's audio track follows the frames." if with_audio else ""),
            f"Context from earlier turns: {ctx.summary() or '(this is the first turn)'}",
            ("Object ids already in use (reuse them for the same objects): "
             + "; ".join(f"{k} ({ctx.known[k]})" for k in known)) if known else "No object ids in use yet.",
            "Answer with the JSON record.",
        ]
        content = [text_part("\n".join(lines)), *(image_part(f.jpeg, "image/jpeg") for f in clip.frames)]
        if with_audio:
            content.append(audio_part(clip.audio_wav, "wav"))
        return [{"role": "system", "content": SYSTEM_PROMPT}, {"role": "user", "content": content}]

    def perceive_clip(self, clip: VideoClip, ctx: PerceptionContext) -> LayeredSegment:
        """One model call (plus at most one repair turn); raises ModelReplyError on a bad reply."""
        tags = {"participant": self.participant, "video": clip.video_id, "turn": clip.turn_id,
                "segment": f"{clip.video_id}#t{clip.turn_id:04d}", "prompt": PROMPT_VERSION}
        try:
            reply = self.backend.chat(self.messages(clip, ctx), role=self.role, response_model=PerceptionReply, tags=tags)
        except ModelServerError as exc:
            if exc.status == 400 and self.audio and clip.audio_wav is not None:
                raise ModelServerError(f"{exc} (if the perception model does not take audio, pass --no-audio)",
                                       url=exc.url, status=exc.status, body=exc.body) from exc
            raise
        return to_segment(reply.parsed, clip, self.participant, ctx.summary())

    def perceive(self, clips: Iterable[VideoClip]) -> Iterator[PerceivedClip]:
        """Clips in order -> perceived clips. A reply that stays invalid after the repair turn
        fails that clip only (the call log records it); a server that fails raises."""
        ctx = PerceptionContext(limit=self.summary_limit)
        for clip in clips:
            try:
                seg = self.perceive_clip(clip, ctx)
            except ModelReplyError as exc:
                yield PerceivedClip(clip, None, str(exc))
                continue
            ctx.update(seg)
            yield PerceivedClip(clip, seg)


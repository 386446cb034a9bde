"""Model-backed offline consolidation and InfMem enrichment (roles "consolidation", "enrichment").

Four kinds of model step, each one call (plus the backend's one repair turn) answered as JSON
and validated with pydantic:

  consolidation, per completed video  the video's objects and its activity log, one line per
                                      10 s segment under a short handle (S1, S2, ...) ->
                                      storage preferences, organizational habits, workflow
                                      patterns and action sequences citing segment handles
  consolidation, across videos        the per-video findings under handles (F1, F2, ...) ->
                                      what holds for the participant, citing findings
  enrichment, routine skills          evidence items (E001, ...: the rule episodes of every
                                      video, then the consolidated patterns) -> routine skills
  enrichment, generated preferences   the same evidence items -> preferences with subtype,
                                      keywords and supporting_evidence_ids (the paper's pass)

Handles are mapped back to segment ids here. A handle or id the model invented is passed on
unchanged, so the collector in `run.py` drops it (and counts it) like any other id that is not
in the bank, and a record left with no existing evidence is not written. Object names link
records to entities only when they name an object of the memory. Prompts are bounded by
`PromptLimits` (segments, objects, findings and evidence items per prompt; characters per line).

A reply that stays invalid after the repair turn fails that step only: the failed call is in
the call log, the step is reported (`StepReport`) and logged as a warning, and the step adds no
records. A model server that cannot be reached raises.
"""

from __future__ import annotations

import logging
import re
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

from memora_graph.consolidate import vocab
from memora_graph.consolidate.memory import ParticipantMemory, Step, display
from memora_graph.consolidate.processors import Processors, StepReport
from memora_graph.consolidate.records import (
    ActionSequence, Consolidation, Enrichment, Episode, GeneratedPreference, OrganizationalHabit, RoutineSkill,
    StoragePreference, VideoConsolidation, WorkflowPattern,
)
from memora_graph.consolidate.rules import RuleEnricher, _uniq
from memora_graph.errors import MemoraError
from memora_graph.llm.backends import (
    ROLES, Backend, CallLog, ModelReplyError, ModelUnavailableError, OpenAIBackend, get_backend,
)

log = logging.getLogger(__name__)

PROMPT_VERSIONS = {"video": "consolidate-video-v1", "participant": "consolidate-participant-v1",
                   "skills": "enrich-skills-v1", "preferences": "enrich-preferences-v1"}
DEFAULT_MODEL = ROLES["consolidation"].default_model
OFFLINE_MESSAGE = (
    "LLM consolidation needs a model server, and the 'offline' backend has none (offline banks use "
    "--processor deterministic). Serve a model with an OpenAI-compatible server, e.g. "
    f"`vllm serve {DEFAULT_MODEL}`, then run: memora consolidate BANK --processor llm --backend openai "
    f"--base-url http://127.0.0.1:8000/v1 --model {DEFAULT_MODEL}"
)
CONTEXTS = ("storage", "during_use", "after_use", "default")
ACTIVITY_TYPES = tuple(sorted(set(vocab.ACTIVITY_TYPE.values())))
ALLOWED_SUBTYPES = ("tool", "storage", "habit", "workflow", "ingredient", "technique", "order", "other")
# Segment summaries that say nothing (the annotation path writes this for a turn without a narration).
_EMPTY_SUMMARIES = frozenset({"", "no narrated action"})


@dataclass(frozen=True)
class PromptLimits:
    """What one prompt may hold; longer inputs are sampled evenly (in time order) or cut."""

    segments_per_video: int = 120
    objects_per_video: int = 40
    findings: int = 150  # per-video findings shown to the participant pass
    episodes: int = 80  # evidence items of the enrichment prompts (rule episodes) ...
    patterns: int = 30  # ... plus consolidated patterns
    steps_per_episode: int = 12
    line_chars: int = 220
    items_per_list: int = 12  # records asked for per list of a consolidation reply
    max_skills: int = 12
    max_preferences: int = 15
    steps_per_skill: int = 12


# -- the reply contract (lenient about what is not worth a repair turn) ---------------------------


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
    """What a consolidation step answers, per video and across videos (METHOD_NOTES section 4)."""

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


# -- prompts ------------------------------------------------------------------------------------

_CONSOLIDATION_FORMAT = """Answer with one JSON object and nothing else:
{"storage_preferences": [{"object": str, "preferred_location": str,
   "context": "storage" | "during_use" | "after_use" | "default", "confidence": 0-1, "evidence": str,
   "supporting_episodes": [handle, ...]}],
 "organizational_habits": [{"habit": str, "trigger": str, "next_action": str, "objects_involved": [str],
   "confidence": 0-1, "supporting_episodes": [handle, ...]}],
 "workflow_patterns": [{"pattern": str, "category": str, "use": str, "then": str, "objects": [str],
   "confidence": 0-1, "supporting_episodes": [handle, ...]}],
 "action_sequences": [{"pattern_name": str, "goal": str, "activity_type": str, "key_objects": [str],
   "key_steps": [str, ...], "confidence": 0-1, "supporting_episodes": [handle, ...]}]}
All four keys are required; a list may be empty. Every item cites at least one handle."""

CONSOLIDATION_SYSTEM = f"""You are the offline consolidation processor of a personal kitchen memory.
You read the completed memories of one person and infer only what they show: where the person keeps
and puts objects (storage preferences), what they habitually do next (organizational habits), how
kinds of objects flow from use to their place (workflow patterns), and recurring multi-step
procedures (action sequences). Do not add general cooking knowledge. Cite evidence only with the
handles given in the input; never make one up.
activity_type is one of: {", ".join(ACTIVITY_TYPES)}.
{_CONSOLIDATION_FORMAT}"""

ENRICHMENT_SYSTEM = """You are the InfMem enrichment processor of a personal kitchen memory. You convert
low-level evidence about one person into reusable participant-level memories for planning. Use only
the evidence ids supplied (E001, E002, ...), never others; prefer concrete object / action / context
statements over generic cooking knowledge. Answer with one JSON object and nothing else, in the
format the task asks for."""


def _clip(text: Any, limit: int) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3].rstrip() + "..."


def _num(x: float) -> str:
    return f"{round(float(x), 1):g}"


def _sample(items: Sequence, cap: int) -> list:
    """At most `cap` items, evenly spaced, in their order."""
    n = len(items)
    if n <= cap:
        return list(items)
    if cap <= 1:
        return list(items[:cap])
    return [items[round(i * (n - 1) / (cap - 1))] for i in range(cap)]


def _resolve(refs: list[str], handles: Handles, kind: type) -> tuple[list, list[str]]:
    """Split cited references into the prompt items of `kind` they name (each once, in citation
    order) and the rest, which are passed on as they are: the collector drops an id that is not
    in the bank."""
    found: dict[int, Any] = {}
    raw = []
    for ref in refs:
        item = handles.get(ref)
        if isinstance(item, kind):
            found.setdefault(id(item), item)
        else:
            raw.append(ref)
    return list(found.values()), raw


def _action(s: Step) -> str:
    text = s.narration or s.text()
    if s.destination and s.destination != s.main.kind and display(s.destination) not in text:
        text += f" -> {display(s.destination)}"
    return text


_HANDLE = re.compile(r"^\[?\s*([A-Za-z]?)\s*0*(\d+)\s*\]?$")


class Handles:
    """The short ids of one prompt ("S3", "F12", "E007") and what each stands for."""

    def __init__(self, prefix: str, width: int = 0):
        self.prefix = prefix
        self.width = width
        self._items: dict[int, Any] = {}

    def add(self, value: Any) -> str:
        n = len(self._items) + 1
        self._items[n] = value
        return f"{self.prefix}{n:0{self.width}d}"

    def get(self, ref: str) -> Any:
        m = _HANDLE.match(ref.strip())
        if not m or (m.group(1) and m.group(1).upper() != self.prefix):
            return None
        return self._items.get(int(m.group(2)))

    def __len__(self) -> int:
        return len(self._items)


class _Names:
    """Object names -> entity ids, for the USES / ABOUT links of model records. Names are not ids:
    a name that matches no object of the memory links nothing."""

    def __init__(self, steps: Iterable[Step]):
        counts: dict[str, Counter[str]] = defaultdict(Counter)
        for s in steps:
            for o in s.objects:
                counts[o.kind][o.entity] += 1
        self._by: dict[str, str] = {}
        for kind, c in counts.items():
            entity = c.most_common(1)[0][0]
            self._by.setdefault(kind.lower(), entity)
            self._by.setdefault(display(kind).lower(), entity)

    def entities(self, names: Iterable[str]) -> list[str]:
        out = []
        for name in names:
            key = " ".join(str(name).lower().replace("_", " ").split())
            entity = self._by.get(key) or (self._by.get(key.split()[-1]) if key else None)
            if entity and entity not in out:
                out.append(entity)
        return out


def _segment_refs(refs: Iterable[str], handles: Handles) -> list[str]:
    """Segment handles -> segment ids; anything else (a real id, or an invented one) unchanged."""
    out = []
    for r in refs:
        v = handles.get(r)
        out.append(v if v is not None else r)
    return _uniq(out)


def _context(value: str) -> str:
    v = value.strip().lower().replace("-", "_").replace(" ", "_")
    return v if v in CONTEXTS else "default"


def _activity(value: str, steps: Iterable[str] = ()) -> str:
    v = value.strip().lower().replace("-", "_").replace(" ", "_")
    if v in ACTIVITY_TYPES:
        return v
    words = " ".join([v, *steps]).lower()
    for key, kind in (("clean", "cleanup_organization"), ("wash", "cleanup_organization"),
                      ("cook", "multi_step_cooking"), ("fry", "multi_step_cooking"), ("boil", "multi_step_cooking"),
                      ("prep", "meal_preparation"), ("cut", "meal_preparation"), ("chop", "meal_preparation"),
                      ("setup", "object_retrieval_setup"), ("retriev", "object_retrieval_setup")):
        if key in words:
            return kind
    return vocab.ACTIVITY_TYPE[None]


def _prep(where: str) -> str:
    return "on" if {"rack", "counter", "board", "hob", "tray", "table", "worktop", "shelf", "stove", "top"} & set(
        where.lower().split()) else "in"


def _storage_statement(obj: str, where: str, context: str) -> str:
    return {
        "storage": f"Typically stores the {obj} {_prep(where)} the {where}",
        "after_use": f"After using the {obj}, usually puts it {_prep(where)} the {where}",
        "during_use": f"Usually uses the {obj} at the {where}",
        "default": f"Usually puts the {obj} {_prep(where)} the {where}",
    }[context]


def _slug(text: str) -> str:
    return "_".join(text.lower().split()) or "object"


def _merge_videos(parts: Iterable[dict[str, int]]) -> dict[str, int]:
    out: Counter[str] = Counter()
    for p in parts:
        out.update(p)
    return dict(sorted(out.items()))


@dataclass
class _Support:
    """What one consolidation item rests on, once its references are resolved."""

    episodes: list[str]
    segments: list[str]
    entities: list[str]
    videos: dict[str, int]
    count: int


def _records(reply: ConsolidationReply, support: Callable[[list[str]], _Support], names: _Names,
             lim: PromptLimits) -> dict[str, list]:
    """A consolidation reply -> the record lists of VideoConsolidation / Consolidation."""
    cap = lim.items_per_list
    out: dict[str, list] = {"storage_preferences": [], "organizational_habits": [], "workflow_patterns": [],
                            "action_sequences": []}
    for it in reply.storage_preferences[:cap]:
        sp = support(it.supporting_episodes)
        obj, ctx, where = it.object.lower(), _context(it.context), it.preferred_location.lower()
        out["storage_preferences"].append(StoragePreference(
            object=_slug(obj), object_name=obj, statement=_storage_statement(obj, where, ctx), preferred_location=where,
            context=ctx, count=sp.count, total=sp.count, confidence=it.confidence, supporting_episodes=sp.episodes,
            entities=_uniq(sp.entities + names.entities([it.object])), videos=sp.videos))
    for it in reply.organizational_habits[:cap]:
        sp = support(it.supporting_episodes)
        out["organizational_habits"].append(OrganizationalHabit(
            trigger=it.trigger or it.habit, next_action=it.next_action, habit=it.habit, count=sp.count,
            trigger_count=sp.count, objects_involved=it.objects_involved, confidence=it.confidence,
            supporting_episodes=sp.episodes, entities=_uniq(sp.entities + names.entities(it.objects_involved)),
            videos=sp.videos))
    for it in reply.workflow_patterns[:cap]:
        sp = support(it.supporting_episodes)
        out["workflow_patterns"].append(WorkflowPattern(
            pattern=it.pattern, category=it.category or "objects", use=it.use, then=it.then, objects=it.objects,
            count=sp.count, confidence=it.confidence, supporting_episodes=sp.episodes,
            entities=_uniq(sp.entities + names.entities(it.objects)), videos=sp.videos))
    for it in reply.action_sequences[:cap]:
        sp = support(it.supporting_episodes)
        steps = [_clip(x, 80) for x in it.key_steps][: lim.steps_per_skill]
        out["action_sequences"].append(ActionSequence(
            title=it.goal or it.pattern_name or " -> ".join(steps[:4]), steps=steps,
            activity_type=_activity(it.activity_type, steps), key_objects=it.key_objects, count=sp.count,
            confidence=it.confidence, supporting_episodes=sp.episodes, segments=sp.segments,
            entities=_uniq(sp.entities + names.entities(it.key_objects)), videos=sp.videos))
    return out


# -- the processors -----------------------------------------------------------------------------


class _ModelStep:
    """What both processors share: the backend, the limits, step reports and the one-call helper."""

    name = "llm"
    role = ""

    def __init__(self, backend: Backend, *, limits: PromptLimits | None = None,
                 reports: list[StepReport] | None = None,
                 on_step: Callable[[str, str], None] | None = None):
        if backend.name == "offline":
            raise ModelUnavailableError(OFFLINE_MESSAGE)
        backend.require(self.role)
        self.backend = backend
        self.limits = limits or PromptLimits()
        self.reports = reports if reports is not None else []
        self.on_step = on_step  # on_step(participant, step): progress before each model call

    def _ask(self, participant: str, step: str, kind: str, video: str, user: str, system: str,
             response_model: type[BaseModel]) -> Any:
        """One model step: the validated reply, or None (reported and logged) if it stayed invalid."""
        if self.on_step is not None:
            self.on_step(participant, step)
        tags = {"participant": participant, "video": video, "prompt": PROMPT_VERSIONS[kind], "step": step}
        messages = [{"role": "system", "content": system}, {"role": "user", "content": user}]
        try:
            reply = self.backend.chat(messages, role=self.role, response_model=response_model, tags=tags)
        except ModelReplyError as exc:
            self.reports.append(StepReport(participant, step, False, str(exc)))
            log.warning("%s: the %s step %r failed and adds no records (its failed call is logged): %s",
                        participant, self.role, step, exc)
            return None
        self.reports.append(StepReport(participant, step, True))
        return reply.parsed


@dataclass
class _Finding:
    kind: str  # storage | habit | workflow | sequence
    video: str
    record: Any

    @property
    def segments(self) -> list[str]:
        return list(self.record.segments) if self.kind == "sequence" else list(self.record.supporting_episodes)


class LLMConsolidator(_ModelStep):
    """Offline consolidation by a model: one call per completed video, then one across videos."""

    role = "consolidation"

    # -- per video ---------------------------------------------------------------------------
    def video_prompt(self, memory: ParticipantMemory, video: str) -> tuple[str, Handles]:
        """The user message for one video and its segment handles ("", empty handles: no evidence)."""
        lim = self.limits
        steps = memory.steps_by_video().get(video, [])
        by_segment: dict[str, list[Step]] = defaultdict(list)
        for s in steps:
            by_segment[s.segment].append(s)
        segments = [g for g in memory.segments if g["video"] == video
                    and (by_segment.get(g["id"]) or (g.get("summary") or "").strip().lower() not in _EMPTY_SUMMARIES)]
        handles = Handles("S")
        if not segments:
            return "", handles
        shown = _sample(segments, lim.segments_per_video)
        log_lines = []
        for g in shown:
            acts = by_segment.get(g["id"], [])
            t0 = g.get("t_start", acts[0].t if acts else 0.0)
            t1 = g.get("t_end", acts[-1].t if acts else t0)
            place = g.get("location") or (acts[0].location if acts else "")
            what = "; ".join(_action(s) for s in acts) if acts else g.get("summary", "")
            log_lines.append(_clip(f"{handles.add(g['id'])} {_num(t0)}-{_num(t1)} s @{place}: {what}", lim.line_chars))

        objects: dict[str, dict] = {}
        for s in steps:
            for i, o in enumerate(s.objects):
                rec = objects.setdefault(o.kind, {"category": o.category, "fixture": o.is_fixture, "n": 0,
                                                  "places": Counter(), "put": Counter()})
                rec["n"] += 1
                if i == 0:
                    rec["places"][s.location] += 1
                    if s.verb in vocab.RELEASING or s.verb == "insert":
                        rec["put"][s.where()[0]] += 1
        ranked = sorted(objects.items(), key=lambda kv: (kv[1]["fixture"], -kv[1]["n"], kv[0]))[: lim.objects_per_video]
        obj_lines = []
        for kind, rec in ranked:
            line = f"- {display(kind)} [{rec['category'] or 'object'}{', fixture' if rec['fixture'] else ''}]: {rec['n']} actions"
            if rec["places"]:
                line += "; at " + ", ".join(p for p, _ in rec["places"].most_common(3) if p)
            if rec["put"]:
                line += "; put " + ", ".join(f"{_prep(w)} {w} x{n}" for w, n in rec["put"].most_common(3))
            obj_lines.append(_clip(line, lim.line_chars))

        head = (f"Participant {memory.participant}, completed video {video}: {len(steps)} narrated actions; "
                f"{len(segments)} segments of 10 s with activity")
        if len(shown) < len(segments):
            head += f"; {len(shown)} segments shown, evenly spaced"
        text = "\n".join([
            head + ".",
            f"Objects ({len(ranked)} of {len(objects)}, most used first):", *obj_lines,
            "Activity log (segment handle, time in the video, place: the narrated actions):", *log_lines,
            "",
            f"Task (prompt {PROMPT_VERSIONS['video']}): consolidate this completed video. Report storage "
            "preferences, organizational habits, workflow patterns and action sequences that this video shows "
            f"(at most {lim.items_per_list} per list, the best supported first). Cite segment handles "
            f"(S1 to S{len(handles)}) in supporting_episodes.",
        ])
        return text, handles

    def consolidate_video(self, memory: ParticipantMemory, video: str) -> VideoConsolidation:
        text, handles = self.video_prompt(memory, video)
        if not text:
            return VideoConsolidation(video=video)
        reply = self._ask(memory.participant, f"video {video}", "video", video, text, CONSOLIDATION_SYSTEM,
                          ConsolidationReply)
        if reply is None:
            return VideoConsolidation(video=video)
        return self._video_records(reply, video, handles, _Names(memory.steps_by_video().get(video, [])))

    def _video_records(self, reply: ConsolidationReply, video: str, handles: Handles, names: _Names) -> VideoConsolidation:
        def support(refs: list[str]) -> _Support:
            segments = _segment_refs(refs, handles)
            return _Support(segments, segments, [], {video: max(len(segments), 1)}, max(len(segments), 1))

        return VideoConsolidation(video=video, **_records(reply, support, names, self.limits))

    # -- across videos -----------------------------------------------------------------------
    def participant_prompt(self, memory: ParticipantMemory, per_video: list[VideoConsolidation]) -> tuple[str, Handles]:
        lim = self.limits
        findings = []
        for v in per_video:
            findings += [_Finding("storage", v.video, r) for r in v.storage_preferences]
            findings += [_Finding("habit", v.video, r) for r in v.organizational_habits]
            findings += [_Finding("workflow", v.video, r) for r in v.workflow_patterns]
            findings += [_Finding("sequence", v.video, r) for r in v.action_sequences]
        handles = Handles("F")
        if not findings:
            return "", handles
        if len(findings) > lim.findings:  # keep the best supported, in their order
            keep = set(sorted(range(len(findings)), key=lambda i: (-findings[i].record.count,
                                                                   -findings[i].record.confidence, i))[: lim.findings])
            findings = [f for i, f in enumerate(findings) if i in keep]
        lines = []
        for f in findings:
            r = f.record
            what = {"storage": lambda: f"{r.statement} [context {r.context}]",
                    "habit": lambda: r.habit,
                    "workflow": lambda: r.pattern,
                    "sequence": lambda: f"{r.title}: {'; '.join(r.steps)}"}[f.kind]()
            kind = "action sequence" if f.kind == "sequence" else f.kind
            lines.append(_clip(f"{handles.add(f)} {f.video} {kind} ({len(f.segments)} segments, confidence "
                               f"{r.confidence:.2f}): {what}", lim.line_chars))
        videos = [v.video for v in per_video]
        text = "\n".join([
            f"Participant {memory.participant}: findings of the per-video consolidation of {len(videos)} completed "
            f"videos ({', '.join(videos)}).",
            "Findings (handle, video, kind, support: statement):", *lines,
            "",
            f"Task (prompt {PROMPT_VERSIONS['participant']}): consolidate across videos. Merge findings that say the "
            "same thing, keep what recurs across videos or is strongly supported, and state it for this person "
            f"(at most {lim.items_per_list} per list). Cite the finding handles (F1 to F{len(handles)}) it rests on "
            "in supporting_episodes.",
        ])
        return text, handles

    def consolidate_participant(self, memory: ParticipantMemory, per_video: list[VideoConsolidation]) -> Consolidation:
        out = Consolidation(participant=memory.participant, videos=[v.video for v in per_video])
        text, handles = self.participant_prompt(memory, per_video)
        if not text:
            return out
        reply = self._ask(memory.participant, "across videos", "participant", "", text, CONSOLIDATION_SYSTEM,
                          ConsolidationReply)
        if reply is None:
            return out

        def support(refs: list[str]) -> _Support:
            """Finding handles -> what the findings rest on; a reference that is no finding of this
            prompt is passed on for the collector to drop."""
            fs, raw = _resolve(refs, handles, _Finding)
            return _Support(episodes=_uniq([x for f in fs for x in f.record.supporting_episodes] + raw),
                            segments=_uniq([x for f in fs for x in f.segments] + raw),
                            entities=_uniq(e for f in fs for e in f.record.entities),
                            videos=_merge_videos(f.record.videos for f in fs),
                            count=max(sum(f.record.count for f in fs), 1))

        return Consolidation(participant=memory.participant, videos=out.videos,
                             **_records(reply, support, _Names(memory.steps), self.limits))


@dataclass
class _Evidence:
    """One enrichment evidence item: a rule episode or a consolidated pattern, and its segments."""

    segments: list[str]
    videos: dict[str, int]
    episode: Episode | None = None
    entities: list[str] = field(default_factory=list)


class LLMEnricher(_ModelStep):
    """InfMem enrichment by a model: routine skills, then generated preferences, over one list of
    evidence items (the rule episodes of every video, then the consolidated patterns)."""

    role = "enrichment"

    def evidence(self, memory: ParticipantMemory, consolidation: Consolidation) -> tuple[str, Handles]:
        lim = self.limits
        rules = RuleEnricher()
        episodes = [ep for _, steps in sorted(memory.steps_by_video().items()) for ep in rules.episodes(steps)]
        handles = Handles("E", width=3)
        lines = []
        shown = _sample(episodes, lim.episodes)
        for ep in shown:
            video, segments = ep[0].video, _uniq(s.segment for s in ep)
            item = _Evidence(segments, {video: 1},
                             Episode(video=video, t_start=round(ep[0].t, 2), t_end=round(ep[-1].t, 2), segments=segments),
                             _uniq(o.entity for s in ep for o in s.objects))
            acts = "; ".join(_action(s) for s in ep[: lim.steps_per_episode])
            if len(ep) > lim.steps_per_episode:
                acts += f"; ... ({len(ep) - lim.steps_per_episode} more)"
            lines.append(_clip(f"{handles.add(item)} {video} {_num(ep[0].t)}-{_num(ep[-1].t)} s @{ep[0].location}: {acts}",
                               lim.line_chars))
        patterns = ([("storage", p, p.statement) for p in consolidation.storage_preferences]
                    + [("habit", h, h.habit) for h in consolidation.organizational_habits]
                    + [("workflow", w, w.pattern) for w in consolidation.workflow_patterns]
                    + [("action sequence", a, f"{a.title}: {'; '.join(a.steps)}") for a in consolidation.action_sequences])
        pattern_lines = []
        for kind, rec, statement in patterns[: lim.patterns]:
            segs = list(rec.segments) if isinstance(rec, ActionSequence) else list(rec.supporting_episodes)
            item = _Evidence(segs, dict(rec.videos), None, list(rec.entities))
            pattern_lines.append(_clip(f"{handles.add(item)} [{kind}, {len(rec.videos)} videos] {statement}", lim.line_chars))
        if not lines and not pattern_lines:
            return "", handles
        head = f"Participant {memory.participant}: evidence items from {len(memory.videos)} completed videos."
        if len(shown) < len(episodes):
            head += f" {len(shown)} of {len(episodes)} episodes shown, evenly spaced."
        parts = [head, "Episodes (evidence id, video, time in the video, place: the narrated actions):", *lines]
        if pattern_lines:
            parts += ["Consolidated patterns (evidence id [kind, support] statement):", *pattern_lines]
        return "\n".join(parts), handles

    def skills_task(self) -> str:
        lim = self.limits
        return (f"Task (prompt {PROMPT_VERSIONS['skills']}): routine skills. Group the episodes that reach the same goal "
                f"into at most {lim.max_skills} routine skills this person repeats. For each give "
                '{"goal": short verb phrase, "activity_type": one of ' + ", ".join(ACTIVITY_TYPES) + ", "
                f'"canonical_steps": [at most {lim.steps_per_skill} short steps in order], "key_objects": [object names], '
                '"supporting_evidence_ids": [the evidence ids it rests on], "confidence": 0-1}. '
                'Answer {"routine_skills": [...]}; the list may be empty.')

    def preferences_task(self, participant: str) -> str:
        lim = self.limits
        return (f"Task (prompt {PROMPT_VERSIONS['preferences']}): generated preferences. participant: {participant}; "
                f"max_skills: {lim.max_preferences}; allowed_subtypes: {', '.join(ALLOWED_SUBTYPES)}. "
                "Write the person's preferences as reusable skill memories (which tool for which action, where things "
                "go, what they do in which order, which ingredients), each "
                '{"subtype": one of the allowed subtypes, "preference": the statement, "keywords": [words a planner '
                'would search for], "objects": [object names], "context": when it applies, "confidence": 0-1, '
                '"evidence_summary": short, "supporting_evidence_ids": [evidence ids]}. '
                'Answer {"generated_preferences": [...]}; the list may be empty.')

    def enrich(self, memory: ParticipantMemory, consolidation: Consolidation) -> Enrichment:
        out = Enrichment(participant=memory.participant)
        evidence, handles = self.evidence(memory, consolidation)
        if not evidence:
            return out
        names = _Names(memory.steps)
        p = memory.participant
        skills = self._ask(p, "routine skills", "skills", "", f"{evidence}\n\n{self.skills_task()}", ENRICHMENT_SYSTEM,
                           SkillsReply)
        if skills is not None:
            out.routine_skills = [self._skill(it, handles, names) for it in skills.routine_skills[: self.limits.max_skills]]
        prefs = self._ask(p, "generated preferences", "preferences", "", f"{evidence}\n\n{self.preferences_task(p)}",
                          ENRICHMENT_SYSTEM, PreferencesReply)
        if prefs is not None:
            out.generated_preferences = [self._preference(it, handles, names)
                                         for it in prefs.generated_preferences[: self.limits.max_preferences]]
        return out

    @staticmethod
    def _cited(refs: list[str], handles: Handles) -> tuple[list[_Evidence], list[str]]:
        items, raw = _resolve(refs, handles, _Evidence)
        return items, _uniq(raw)

    def _skill(self, it: SkillItem, handles: Handles, names: _Names) -> RoutineSkill:
        items, raw = self._cited(it.supporting_evidence_ids, handles)
        episodes = [i.episode for i in items if i.episode is not None]
        first = [e.segments[0] for e in episodes] + [s for i in items if i.episode is None for s in i.segments]
        steps = [_clip(s, 80) for s in it.canonical_steps][: self.limits.steps_per_skill]
        return RoutineSkill(
            goal=it.goal, activity_type=_activity(it.activity_type, steps), canonical_steps=steps,
            key_objects=it.key_objects, supporting_episodes=_uniq(first + raw),
            segments=_uniq([s for i in items for s in i.segments] + raw), episodes=episodes, count=max(len(items), 1),
            confidence=it.confidence, entities=names.entities(it.key_objects),
            videos=_merge_videos(i.videos for i in items))

    def _preference(self, it: PreferenceItem, handles: Handles, names: _Names) -> GeneratedPreference:
        items, raw = self._cited(it.supporting_evidence_ids, handles)
        subtype = it.subtype.strip().lower()
        return GeneratedPreference(
            subtype=subtype if subtype in ALLOWED_SUBTYPES else "other", preference=it.preference,
            keywords=_uniq(k.lower() for k in it.keywords)[:12], objects=it.objects, context=it.context,
            count=max(len(items), 1), confidence=it.confidence,
            evidence_summary=it.evidence_summary or f"{len(items)} evidence item(s)",
            supporting_evidence_ids=_uniq([s for i in items for s in i.segments] + raw),
            entities=names.entities(it.objects), videos=_merge_videos(i.videos for i in items))


# -- the factory ----------------------------------------------------------------------------------


def make_llm_processors(
    backend: Backend | str = "openai",
    call_log: CallLog | None = None,
    *,
    model: str | None = None,
    consolidation_model: str | None = None,
    enrichment_model: str | None = None,
    enrichment_backend: Backend | None = None,
    limits: PromptLimits | None = None,
    on_step: Callable[[str, str], None] | None = None,
    concurrency: int = 1,
    **backend_options: Any,
) -> Processors:
    """The "llm" processors. `backend` is a backend instance or a registered backend name built
    here with `backend_options` (base_url, api_key, timeout_s, ...); `consolidation_model` (or
    `model`) and `enrichment_model` (default: the same) pick the models. Every call goes to one
    call log: `call_log`, or the given backend's. `concurrency`: per-video consolidation calls in
    flight at once (the bank written does not depend on it)."""
    if concurrency < 1:
        raise MemoraError(f"--concurrency must be at least 1, got {concurrency}")
    if isinstance(backend, str):
        if backend == "offline":
            raise ModelUnavailableError(OFFLINE_MESSAGE)
        log_ = call_log if call_log is not None else CallLog()
        cons_model = consolidation_model or model
        enr_model = enrichment_model or cons_model

        def build(m: str | None) -> Backend:
            return get_backend(backend, call_log=log_, **backend_options, **({"model": m} if m else {}))

        cons = build(cons_model)
        enr = enrichment_backend or (cons if enr_model == cons_model else build(enr_model))
    else:
        if backend_options or model or consolidation_model or enrichment_model:
            raise MemoraError("make_llm_processors: with a backend instance, configure models and options on the "
                              "backend (or pass enrichment_backend); got "
                              + ", ".join(sorted({*backend_options, *(k for k, v in (
                                  ("model", model), ("consolidation_model", consolidation_model),
                                  ("enrichment_model", enrichment_model)) if v)})))
        if call_log is not None and call_log is not backend.call_log:
            raise MemoraError("make_llm_processors: the calls go to the backend's call log; give the CallLog to get_backend")
        cons, enr = backend, enrichment_backend or backend
        log_ = backend.call_log
    if enr.call_log is not log_:
        raise MemoraError("make_llm_processors: the enrichment backend must share the consolidation backend's call log")
    reports: list[StepReport] = []
    return Processors("llm", LLMConsolidator(cons, limits=limits, reports=reports, on_step=on_step),
                      LLMEnricher(enr, limits=limits, reports=reports, on_step=on_step), call_log=log_, reports=reports,
                      concurrency=concurrency)


def check_servers(processors: Processors) -> list[str]:
    """Reach every OpenAI-compatible server of the processors before any work (a server that is
    not running fails here, with its URL) and pick its model if none was named. Returns warnings,
    e.g. a named model the server does not list."""
    warnings = []
    seen = set()
    for proc in (processors.consolidation, processors.enrichment):
        backend = getattr(proc, "backend", None)
        if not isinstance(backend, OpenAIBackend) or id(backend) in seen:
            continue
        seen.add(id(backend))
        models = backend.list_models()
        if backend.model is None:
            backend.resolve_model()
        elif models and backend.model not in models:
            warnings.append(f"{backend.options.base_url} does not list model {backend.model!r} "
                            f"(it lists: {', '.join(models)}); calls may fail")
    return warnings

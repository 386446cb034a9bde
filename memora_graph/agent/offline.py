"""The `offline` answer policy: a deterministic reader that uses the same tools and the same loop as
a model, so every condition runs on a CPU with no model. It is NOT a language model; numbers it
produces measure the memories through a fixed reader, not an LLM's reasoning.

EAM-QA: the typed question reader (`agent.reading`). It parses the question into an intent (a
habit, a preference or method, a routine, or recall of one video; its actions and objects as EPIC
classes), makes the typed lookups the intent needs with whatever tools the condition advertises
(`agent.lookups`: the episodes around the subject, the person's habits and preferences, routines,
the named video's log, whether the subject is in memory at all), turns every record returned into
actions and objects (`agent.evidence`), and scores each option by how its actions and objects
occur in that evidence and how close it is in meaning to the records. It answers the best option
with the evidence ids behind it, or E: when memory holds no record of the subject, or when no
option is supported well enough. At most 3 calls per response, four tool rounds.

Parametric (no tools) is a closed-book prior: the content option closest to the question stem,
never E.

Planning: it retrieves a routine first (get_routine_skill, else search_activities, else search),
grounds up to two objects through the entity tools (search_objects, else get_object_history,
else search), and writes numbered steps "Verb the object at the place" from the routine's steps
or, without a routine, from the best-matching remembered activity sequence. Where the condition
has preferences (MEMORA's get_preferences), the plan honours the ones about its objects: it puts
an object back where the person keeps it, adds a habitual next action, follows a workflow
(`apply_preferences`).

The policy reads only the task view and its own tool results; never gold answers or references.
"""

from __future__ import annotations

import hashlib
import json
import re
from typing import Any

import numpy as np

from memora_graph.agent import lookups
from memora_graph.agent.confidence import load_calibration
from memora_graph.agent.evidence import budgeted_events
from memora_graph.agent.loop import AgentState, PolicyReply
from memora_graph.agent.reading import Decision, parse_question, score
from memora_graph.baselines.flat1d import FlatHit
from memora_graph.baselines.graph2d import GraphNode
from memora_graph.consolidate.vocab import past_tense
from memora_graph.embed import get_embedder
from memora_graph.errors import MemoraError
from memora_graph.retrieve.results import (
    ActivityRecord, ObjectRecord, OtherMatch, PlaceRecord, PreferenceRecord, Record, RoutineRecord, RoutinesResult,
    ToolResult, VisibleObject,
)
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.text import KITCHEN_NOUNS, tokenize

ROUTINE_ADOPT = 0.5
MAX_STEPS = 12
MAX_PREFERENCES = 4  # retrieved preferences considered for one plan
MAX_PREFERENCE_STEPS = 3  # steps a plan may gain from them
EVIDENCE_PER_CALL = 6  # the best results of each call are read
EVIDENCE_CHARS = 240
_KITCHEN = frozenset(KITCHEN_NOUNS)


def _call(name: str, **arguments: Any) -> dict[str, Any]:
    args = json.dumps(arguments, sort_keys=True)
    digest = hashlib.sha256(f"{name}:{args}".encode()).hexdigest()[:10]
    return {"id": f"offline_{digest}", "type": "function",
            "function": {"name": name, "arguments": args}}


def _tool_names(tools: list[dict[str, Any]]) -> list[str]:
    return [t["function"]["name"] for t in tools if isinstance(t, dict) and "function" in t]


def _stem(question: str) -> str:
    return question.split("\n\nIMPORTANT:")[0].strip()


def _clean(text: str) -> str:
    """A record's line as the reader scores it: no leading time stamp, words not ids, bounded."""
    return re.sub(r"^\[[^\]]*\]\s*", "", text).replace("_", " ")[:EVIDENCE_CHARS]


def evidence_items(result: Any) -> list[dict[str, Any]]:
    """The evidence of one typed tool result: {text, video, kind (the result's list), record} per
    record that has words, in the result's order."""
    if not isinstance(result, ToolResult):
        return []
    out = []
    for kind, rec in result.records():
        text = _clean(rec.text())
        if text:
            out.append({"text": text, "video": rec.from_video(), "kind": kind, "record": rec})
    return out


def read_evidence(result: Any, n: int = EVIDENCE_PER_CALL) -> list[dict[str, Any]]:
    """The first `n` evidence items a reader takes from one tool result, round-robin across the
    result's record kinds (objects, activities, places, patterns, ...), each kind in its own
    rank order. A multi-store `search` result is thereby read across every store it returns,
    not only its first one or two lists."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for it in evidence_items(result):
        groups.setdefault(it["kind"], []).append(it)
    out: list[dict[str, Any]] = []
    depth = 0
    while len(out) < n and any(depth < len(g) for g in groups.values()):
        for g in groups.values():
            if depth < len(g) and len(out) < n:
                out.append(g[depth])
        depth += 1
    return out




class OfflinePolicy:
    """Deterministic reader for EAM-QA and planning (see the module docstring)."""

    name = "offline"

    def __init__(self, evidence_budget: int | None = None, calibration: str | None = None):
        """`evidence_budget`: the reader reads at most this many records of its tool results (the
        budget experiment; None: all). `calibration`: a calibration file (default: the package's
        `agent/calibration.json`), or "none" for the fixed rules without a probability."""
        self.embedder = get_embedder()
        if evidence_budget is not None and int(evidence_budget) < 1:
            raise MemoraError(f"evidence_budget must be at least 1 record, got {evidence_budget}")
        self.evidence_budget = int(evidence_budget) if evidence_budget is not None else None
        off = calibration is not None and str(calibration).lower() == "none"
        self.calibration = None if off else load_calibration(calibration)

    def respond(self, messages, tools, *, forced: bool, state: AgentState) -> PolicyReply:
        if state.task_kind == "eam_qa":
            return self._qa(tools, forced, state)
        return self._plan(tools, forced, state)

    # -- EAM-QA ----------------------------------------------------------------------------
    def _qa(self, tools, forced, state: AgentState) -> PolicyReply:
        view = state.view
        names = _tool_names(tools)
        if not forced and names:
            rounds = lookups.plan(parse_question(view["question"], self.lexicon), names)
            if state.iteration < len(rounds):
                return PolicyReply(content="", tool_calls=[_call(n, **a) for n, a in rounds[state.iteration]])
        letter, detail = self.choose(view, state.calls)
        return PolicyReply(content=f"{detail}\nAnswer: {letter}")

    @property
    def lexicon(self) -> Lexicon:
        return Lexicon.load()

    def embed(self, texts: list[str]):
        """Query-encoder vectors of the reader's texts, each encoded alone and kept between runs
        (memora_graph/vector_store.py): the same vectors in every process, run and worker split."""
        from memora_graph.vector_store import query_vectors

        return query_vectors(self.embedder).encode(texts)

    def decide(self, view: dict[str, Any], calls: list[dict[str, Any]]) -> Decision:
        """The typed reader's decision over the tool results of the calls made."""
        results = [c["result"] for c in calls if isinstance(c["result"], ToolResult)]
        events = budgeted_events(results, self.lexicon, self.evidence_budget)
        return score(view["question"], view["choices"], events, self.lexicon, embed=self.embed,
                     calibration=self.calibration)

    def choose(self, view: dict[str, Any], calls: list[dict[str, Any]]) -> tuple[str, str]:
        choices = view["choices"][:4]
        if not calls:  # closed-book prior (Parametric)
            q = self.embed([_stem(view["question"])])[0]
            c = self.embed(choices)
            best = int(np.argmax(c @ q))
            return "ABCD"[best], "Closed-book prior: no memory available."
        d = self.decide(view, calls)
        cited = d.support["ABCD".index(d.letter)] if d.letter in "ABCD" else []
        detail = f"{d.text()}" + (f"; evidence: {', '.join(cited[:8])}" if cited else "")
        if d.probability is not None:
            detail += f"\nConfidence: {d.probability:.4f}"
        best = max(range(len(d.scores)), key=lambda i: (d.scores[i], -i))
        features = {k: round(v, 5) for k, v in d.features.items()} | {"best_letter": "ABCD"[best]}
        detail += f"\nFeatures: {json.dumps(features, sort_keys=True)}"
        return d.letter, detail

    # -- Planning ---------------------------------------------------------------------------
    def _plan(self, tools, forced, state: AgentState) -> PolicyReply:
        names = _tool_names(tools)
        query = _task_text(state.view["task_query"])
        if not forced and names:
            if state.iteration == 0:
                first = []
                if "get_routine_skill" in names:
                    first.append(_call("get_routine_skill", goal_query=query))
                    if "get_preferences" in names:
                        first.append(_call("get_preferences", query=query))
                elif "search_activities" in names:
                    first.append(_call("search_activities", query=query))
                else:
                    first.append(_call("search", query=query))
                return PolicyReply(tool_calls=first)
            if state.iteration == 1:
                nouns = self._nouns_to_ground(query, state.calls)
                routine, sim = self._routine(state.calls)
                extra = []
                if "get_routine_skill" in names and sim < ROUTINE_ADOPT and "search_activities" in names:
                    extra = [_call("search_activities", query=query)]  # no usable routine: episodes once
                    nouns = nouns[:2]
                if nouns or extra:
                    if "search_objects" in names:
                        calls = [_call("search_objects", query=n) for n in nouns]
                    elif "get_object_history" in names:
                        calls = [_call("get_object_history", object_query=n) for n in nouns]
                    else:
                        calls = [_call("search", query=n) for n in nouns if n != query]
                    if calls or extra:
                        return PolicyReply(tool_calls=(extra + calls)[:3])
        steps = self.compose_plan(state.view["task_query"], state.calls)
        return PolicyReply(content="Plan:\n" + "\n".join(f"{i}. {s}" for i, s in enumerate(steps, 1)))

    def _routine(self, calls) -> tuple[RoutineRecord | None, float]:
        for c in calls:
            if c["name"] == "get_routine_skill" and isinstance(c["result"], RoutinesResult) and c["result"].routines:
                r = c["result"].routines[0]
                return r, float(r.similarity or 0)
        return None, 0.0

    def _nouns_to_ground(self, query: str, calls) -> list[str]:
        routine, sim = self._routine(calls)
        nouns: list[str] = []
        if routine is not None and sim >= ROUTINE_ADOPT:
            nouns = [o.object.replace("_", " ") for o in routine.key_objects]
        nouns += [w for w in re.findall(r"[a-z]+", query.lower()) if w in _KITCHEN]
        return list(dict.fromkeys(n for n in nouns if n))[:2]

    def _grounding(self, calls) -> dict[str, dict[str, str]]:
        """noun -> {label, location} from the entity-tool results."""
        out: dict[str, dict[str, str]] = {}
        for c in calls:
            if c["name"] not in ("search_objects", "get_object_history", "search"):
                continue
            noun = str(next(iter(c["arguments"].values()), "")).lower()
            for it in evidence_items(c["result"]):
                found = _object_fields(it["record"])
                if found is None:
                    continue
                name, loc, color, material = found
                name = name.lower()
                if not name or (noun and noun not in name and name not in noun):
                    continue
                label = " ".join(x for x in (color, material, name) if x)
                out.setdefault(name, {"label": label.strip(), "location": str(loc).replace("_", " ")})
        return out

    def compose_plan(self, task_query: str, calls: list[dict[str, Any]]) -> list[str]:
        return [s["text"] for s in self.structured_plan(task_query, calls)]

    def structured_plan(self, task_query: str, calls: list[dict[str, Any]]) -> list[dict[str, Any]]:
        query = _task_text(task_query)
        routine, sim = self._routine(calls)
        raw_steps: list[tuple[str, str]] = []  # (narration, place)
        if routine is not None and sim >= ROUTINE_ADOPT:
            raw_steps = [(s.action, "") for s in routine.canonical_steps]
        if not raw_steps:
            raw_steps = self._activity_steps(query, calls)
        if not raw_steps:
            return generic_plan(task_query)
        grounding = self._grounding(calls)
        out: list[dict[str, Any]] = []
        for narration, place in raw_steps:
            verb, obj = _split_narration(narration)
            if not verb:
                continue
            g = next((v for k, v in grounding.items() if obj and (k in obj or obj in k)), None)
            entity = g["label"] if g else obj or "item"
            location = (g["location"] if g and g["location"] else place) or "counter"
            step = _step(verb, entity, location, grounded=g is not None)
            if not out or out[-1]["text"].lower() != step["text"].lower():
                out.append(step)
        out = out[:MAX_STEPS]
        if out:
            out = apply_preferences(out, self._preferences(query, calls, out))
        return out or generic_plan(task_query)

    def _preferences(self, query: str, calls, steps: list[dict[str, Any]]) -> list[PreferenceRecord]:
        """The retrieved preferences that concern this plan: one of their objects is an object of
        the plan or of the request; best retrieval similarity first."""
        prefs = [it["record"] for c in calls if c["name"] in ("get_preferences", "search_patterns", "search")
                 for it in evidence_items(c["result"]) if isinstance(it["record"], PreferenceRecord)]
        nouns = {w for s in steps for w in str(s["entity"]).split()} | set(re.findall(r"[a-z]+", query.lower()))
        relevant: dict[str, PreferenceRecord] = {}
        for p in sorted(prefs, key=lambda p: -float(p.similarity or 0)):
            if any(w in nouns for o in p.objects for w in o.lower().split()):
                relevant.setdefault(p.preference_id, p)
        return list(relevant.values())[:MAX_PREFERENCES]

    def _activity_steps(self, query: str, calls) -> list[tuple[str, str]]:
        acts = [(it, fields) for c in calls if c["name"] in ("search", "search_activities")
                for it in evidence_items(c["result"]) if (fields := _activity_fields(it["kind"], it["record"]))]
        if not acts:
            return []
        texts = [it["text"] for it, _ in acts]
        from memora_graph.vector_store import query_vectors

        # the reader's own encoder on both sides (no torch in an evaluation whose caches are warm)
        sims = query_vectors(self.embedder, kind="passage").encode(texts) @ self.embed([query])[0]
        ranked = [acts[i][1] for i in np.argsort(-sims, kind="stable")[:2]]
        steps: list[tuple[str, str]] = []
        for text, place in ranked:
            text = re.sub(r"^\[[^\]]*\]\s*", "", text)
            place = re.sub(r"\s*\(.*$", "", place.replace("_", " "))
            for part in re.split(r"[;.]\s*", text):
                if part.strip():
                    steps.append((part.strip(), place))
        return steps


def _step(action: str, entity: str, location: str, *, grounded: bool, preference: str | None = None) -> dict[str, Any]:
    step = {"action": action, "entity": entity, "location": location, "grounded": grounded,
            "text": f"{action.capitalize()} the {entity} {_prep(location)} the {location}"}
    if preference:
        step["preference"] = preference
    return step


def _prep(location: str) -> str:
    return "in" if location.split()[-1:] and location.split()[-1] in ("sink", "drawer", "cupboard", "fridge", "bin",
                                                                     "box", "bag", "basket") else "at"


def _object_fields(rec: Record) -> tuple[str, str, str, str] | None:
    """(name, location, colour, material) of a record that names an object, else None."""
    if isinstance(rec, ObjectRecord):
        vis = rec.visual_properties
        return rec.name, rec.spatial_info.location, vis.get("color", ""), vis.get("material", "")
    if isinstance(rec, VisibleObject):
        return rec.name, rec.location, "", ""
    if isinstance(rec, (PlaceRecord, OtherMatch)):
        return rec.name, "", "", ""
    if isinstance(rec, GraphNode) and rec.name:
        return rec.name, rec.location or "", "", ""
    return None


def _activity_fields(kind: str, rec: Record) -> tuple[str, str] | None:
    """(what was done, where) of an activity record of any memory, else None."""
    if isinstance(rec, ActivityRecord):
        return rec.summary, rec.environment
    if isinstance(rec, FlatHit) and rec.kind == "activity":
        return rec.text(), ""
    if isinstance(rec, GraphNode) and kind == "activities":
        return rec.text(), rec.place or ""
    return None


def _matches(step: dict[str, Any], obj: str, verb: str | None = None) -> bool:
    entity = str(step["entity"]).lower()
    if not obj or not any(w in entity.split() for w in obj.lower().split()):
        return False
    return verb is None or tokenize(verb) <= tokenize(step["action"]) or tokenize(step["action"]) <= tokenize(verb)


def _after_words(text: str | None) -> str:
    """"put on drying rack" -> "drying rack": the place a workflow's follow-up puts things."""
    words = (text or "").split(" ", 2)
    return words[2] if len(words) == 3 and words[0] == "put" and words[1] in ("in", "on", "at", "into") else ""


def apply_preferences(steps: list[dict[str, Any]], prefs: list[PreferenceRecord]) -> list[dict[str, Any]]:
    """Honour retrieved preferences in a plan, the way a person's helper would, reading each
    preference's structured fields:

    - storage (object, preferred location; context storage, after use or default): after the last
      step with the object, put it back where the person keeps it (unless the plan already does);
    - habit (trigger, next action: "empty pan" -> "wash pan"): after a step that does the trigger,
      add the habitual next action (unless it already follows);
    - workflow (objects, use "wash @ sink", then "put on drying rack"): after the plan uses one of
      those objects that way, add the follow-up.

    Each added step names the preference it honours; at most MAX_PREFERENCE_STEPS are added."""
    out = list(steps)
    added = 0
    for p in prefs:
        if added >= MAX_PREFERENCE_STEPS:
            break
        objects = [o.lower().replace("_", " ") for o in p.objects]
        new: tuple[int, dict[str, Any]] | None = None
        if p.subtype == "storage" and objects and p.preferred_location and p.context != "during_use":
            place = p.preferred_location.strip(" .").lower()
            idx = [i for i, s in enumerate(out) if _matches(s, objects[0])]
            if idx and not any(_matches(s, objects[0]) and s["location"] == place for s in out):
                new = (idx[-1] + 1, _step("put", out[idx[-1]]["entity"], place, grounded=True,
                                          preference=p.preference_id))
        elif p.subtype == "habit":
            trigger, nxt = (p.trigger or "").split(), (p.next_action or "").split()
            if len(trigger) >= 2 and len(nxt) >= 2:
                idx = [i for i, s in enumerate(out) if _matches(s, " ".join(trigger[1:]), trigger[0])]
                if idx:
                    i = idx[0]
                    verb, obj = nxt[0], " ".join(nxt[1:])
                    follow = out[i + 1] if i + 1 < len(out) else None
                    if follow is None or not _matches(follow, obj, verb):
                        new = (i + 1, _step(verb, obj, out[i]["location"], grounded=True, preference=p.preference_id))
        elif p.subtype == "workflow" and objects and p.use and (place := _after_words(p.then)):
            # the use is matched on its participle ("washed"), the word the statement uses
            used = past_tense(p.use.split(" @ ")[0])
            idx = [i for i, s in enumerate(out) if re.fullmatch(r"\w+", used) and any(_matches(s, o, used) for o in objects)]
            place = place.strip(" .").lower()
            if idx and not any(s["location"] == place for s in out[idx[-1] + 1:]):
                i = idx[-1]
                new = (i + 1, _step("put", out[i]["entity"], place, grounded=True, preference=p.preference_id))
        if new is not None:
            out.insert(*new)
            added += 1
    return out[:MAX_STEPS + MAX_PREFERENCE_STEPS]


_HELP = re.compile(r"^\s*help\s+(?:p\d+|the participant|the person)\s+(?:to\s+)?", re.I)


def _task_text(task_query: str) -> str:
    return _HELP.sub("", task_query).strip().rstrip(".")


def _split_narration(text: str) -> tuple[str, str]:
    words = re.sub(r"[^a-z\s-]", " ", text.lower()).split()
    words = [w for w in words if w not in ("person", "the", "a", "an", "they", "he", "she")]
    if not words:
        return "", ""
    two = " ".join(words[:2])
    if two in ("pick up", "put down", "turn on", "turn off", "put in", "put into", "put on", "take out"):
        return two, " ".join(words[2:])
    return words[0].replace("-", " "), " ".join(words[1:])


def generic_plan(task_query: str) -> list[dict[str, Any]]:
    """A plan from the request alone (Parametric, or nothing retrieved): locate, take, act, put back."""
    query = _task_text(task_query).lower()
    nouns = [w for w in re.findall(r"[a-z]+", query) if w in _KITCHEN] or [re.findall(r"[a-z]+", query)[-1] if query else "item"]
    noun = nouns[0]
    verbs = [w for w in re.findall(r"[a-z]+", query) if w in ("wash", "dry", "cut", "peel", "stir", "pour", "rinse", "wipe",
                                                               "fry", "boil", "chop", "slice", "mix", "fill", "open", "close")]
    verbs = verbs or ["prepare"]
    steps = [("take", noun, "counter")]
    for v in verbs:
        steps.append((v, noun, "sink" if v in ("wash", "rinse", "dry", "fill") else "counter"))
    steps.append(("place", noun, "counter"))
    return [_step(a, e, loc, grounded=False) for a, e, loc in steps]

"""The `offline` answer policy: a deterministic reader that uses the same tools and the same loop as
a model, so every condition runs on a CPU with no model. It is NOT a language model; numbers it
produces measure the memories through a fixed, simple reader, not an LLM's reasoning.

EAM-QA: it searches the question stem, then each content option (3 calls per iteration, so two
tool rounds), then scores each option against the retrieved evidence:

    support(option) = max cosine(option, evidence text)            (MiniLM, query vs passage)
                    + LEXICAL_WEIGHT * share of the option's content words found in the evidence

and answers the best option, or E when the best support is below E_THRESHOLD (weak evidence) or
within E_MARGIN of the runner-up (evidence that does not discriminate). On ERecall items naming a
video, evidence from that video is preferred when the tools report videos.

Parametric (no tools) is a closed-book prior: the content option closest to the question stem,
never E.

Planning: it retrieves a routine first (get_routine_skill, else search_activities, else search),
grounds up to two objects through the entity tools (search_objects, else get_object_history,
else search), and writes numbered steps "Verb the object at the place" from the routine's steps
or, without a routine, from the best-matching remembered activity sequence.

The policy reads only the task view and its own tool results; never gold answers or references.
"""

from __future__ import annotations

import hashlib
import json
import re
from typing import Any

import numpy as np

from memora_graph.agent.loop import AgentState, PolicyReply
from memora_graph.bench.metrics import KITCHEN_NOUNS, tokenize
from memora_graph.embed import get_embedder

E_THRESHOLD = 0.62
E_MARGIN = 0.01
LEXICAL_WEIGHT = 0.3
ROUTINE_ADOPT = 0.5
MAX_STEPS = 12
EVIDENCE_PER_CALL = 6  # the best results of each call are read
EVIDENCE_CHARS = 240
_VIDEO = re.compile(r"\bP\d{2}_\d{2,3}\b")
_VIDEO_KEYS = ("video", "video_id", "source_video")
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


_PRIMARY = ("summary", "text", "description", "statement", "preference", "goal")
_NOT_EVIDENCE = frozenset({"used_with", "places", "score", "time_seen_seconds", "arguments", "routing", "evidence",
                           "action_breakdown", "supporting_episodes", "_context", "canonical_steps", "steps",
                           "key_objects", "time", "visual_properties", "spatial_info", "state"})


def _field(value: Any, *keys: str) -> str:
    if isinstance(value, dict):
        return next((str(value[k]) for k in keys if value.get(k)), "")
    return str(value or "")


def _item_text(d: dict[str, Any]) -> str:
    """The one text a reader takes from a record: its summary / text / description / statement /
    goal, or for an object record "name: state at place"; routine steps are appended."""
    text = next((d[k] for k in _PRIMARY if isinstance(d.get(k), str) and d[k]), "")
    if not text and (d.get("name") or d.get("label")):
        state = _field(d.get("state"), "current_state") or str(d.get("current_state") or "")
        place = (_field(d.get("spatial_info"), "place", "location") or str(d.get("location") or "")
                 or str(d.get("current_location") or ""))
        text = str(d.get("label") or d.get("name")) + (f": {state}" if state else "") + (f" at {place}" if place else "")
    steps = d.get("canonical_steps") or d.get("steps")
    if text and isinstance(steps, list):
        text += ": " + "; ".join(_field(x, "action") if isinstance(x, dict) else str(x) for x in steps)
    return re.sub(r"^\[[^\]]*\]\s*", "", text).replace("_", " ")[:EVIDENCE_CHARS]


def evidence_items(result: Any, kind: str = "") -> list[dict[str, Any]]:
    """Flatten any tool result into evidence items {text, video, kind, raw}: every record (a dict
    with a text-like field or an object name) becomes one item; bookkeeping fields are skipped."""
    out: list[dict[str, Any]] = []
    if isinstance(result, list):
        for x in result:
            out.extend(evidence_items(x, kind))
    elif isinstance(result, dict):
        if kind:  # the top level of a tool result is an envelope, not a record
            text = _item_text(result)
            if text:
                video = next((str(result[k]) for k in _VIDEO_KEYS if result.get(k)), "")
                out.append({"text": text, "video": video, "kind": kind, "raw": result})
        for k, v in result.items():
            if isinstance(v, (list, dict)) and k not in _NOT_EVIDENCE:
                out.extend(evidence_items(v, k))
    return out


class OfflinePolicy:
    """Deterministic reader for EAM-QA and planning (see the module docstring)."""

    name = "offline"

    def __init__(self):
        self.embedder = get_embedder()

    def respond(self, messages, tools, *, forced: bool, state: AgentState) -> PolicyReply:
        if state.task_kind == "eam_qa":
            return self._qa(tools, forced, state)
        return self._plan(tools, forced, state)

    # -- EAM-QA ----------------------------------------------------------------------------
    def _qa(self, tools, forced, state: AgentState) -> PolicyReply:
        view = state.view
        stem = _stem(view["question"])
        names = _tool_names(tools)
        if not forced and names:
            tool = "search" if "search" in names else names[0]
            arg = "query" if tool != "get_object_history" else "object_query"
            queries = [stem] + [c for c in view["choices"][:4]]
            todo = queries[len(state.calls):len(state.calls) + 3]
            if todo:
                return PolicyReply(content="", tool_calls=[_call(tool, **{arg: q}) for q in todo])
        letter, detail = self.choose(view, state.calls)
        return PolicyReply(content=f"{detail}\nAnswer: {letter}")

    def choose(self, view: dict[str, Any], calls: list[dict[str, Any]]) -> tuple[str, str]:
        choices = view["choices"][:4]
        stem = _stem(view["question"])
        if not calls:  # closed-book prior (Parametric)
            q = self.embedder.encode([stem], kind="query")[0]
            c = self.embedder.encode(choices, kind="query")
            best = int(np.argmax(c @ q))
            return "ABCD"[best], "Closed-book prior: no memory available."
        items = [it for call in calls for it in evidence_items(call["result"])[:EVIDENCE_PER_CALL]]
        videos = set(_VIDEO.findall(stem))
        if videos and any(it["video"] in videos for it in items):
            items = [it for it in items if it["video"] in videos]
        texts = list(dict.fromkeys(it["text"] for it in items if it["text"]))
        if not texts:
            return "E", "No evidence retrieved."
        ev = self.embedder.encode(texts, kind="passage")
        cv = self.embedder.encode(choices, kind="query")
        sims = cv @ ev.T
        ev_tokens = set().union(*(tokenize(t) for t in texts))
        scores = []
        for i, choice in enumerate(choices):
            words = tokenize(choice)
            lexical = len(words & ev_tokens) / len(words) if words else 0.0
            scores.append(float(sims[i].max()) + LEXICAL_WEIGHT * lexical)
        order = sorted(range(4), key=lambda i: (-scores[i], i))
        best, second = order[0], order[1]
        detail = "Support: " + ", ".join(f"{'ABCD'[i]}={scores[i]:.3f}" for i in range(4))
        if scores[best] < E_THRESHOLD or scores[best] - scores[second] < E_MARGIN:
            return "E", detail + " (weak or non-discriminating evidence)"
        return "ABCD"[best], detail

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

    def _routine(self, calls) -> tuple[dict | None, float]:
        for c in calls:
            if c["name"] == "get_routine_skill" and isinstance(c["result"], dict):
                routines = c["result"].get("routines") or []
                if routines:
                    r = routines[0]
                    return r, float(r.get("similarity") or 0)
        return None, 0.0

    def _nouns_to_ground(self, query: str, calls) -> list[str]:
        routine, sim = self._routine(calls)
        nouns: list[str] = []
        if routine is not None and sim >= ROUTINE_ADOPT:
            nouns = [str(o.get("object", o) if isinstance(o, dict) else o).replace("_", " ")
                     for o in routine.get("key_objects") or []]
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
                raw = it["raw"]
                name = str(raw.get("name") or "").lower()
                if not name or (noun and noun not in name and name not in noun):
                    continue
                loc = raw.get("location") or raw.get("current_location") or ""
                spatial = raw.get("spatial_info")
                if not loc and isinstance(spatial, dict):
                    loc = spatial.get("location") or ""
                vis = raw.get("visual_properties") if isinstance(raw.get("visual_properties"), dict) else {}
                label = " ".join(x for x in (vis.get("color") or raw.get("color") or "",
                                             vis.get("material") or raw.get("material") or "", name) if x)
                out.setdefault(name, {"label": label.strip(), "location": str(loc).replace("_", " ")})
        return out

    def compose_plan(self, task_query: str, calls: list[dict[str, Any]]) -> list[str]:
        return [s["text"] for s in self.structured_plan(task_query, calls)]

    def structured_plan(self, task_query: str, calls: list[dict[str, Any]]) -> list[dict[str, Any]]:
        query = _task_text(task_query)
        routine, sim = self._routine(calls)
        raw_steps: list[tuple[str, str]] = []  # (narration, place)
        if routine is not None and sim >= ROUTINE_ADOPT:
            for s in routine.get("canonical_steps") or []:
                raw_steps.append((str(s.get("action", s) if isinstance(s, dict) else s), ""))
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
            step = {"action": verb, "entity": entity, "location": location, "grounded": g is not None,
                    "text": f"{verb.capitalize()} the {entity} at the {location}"}
            if not out or out[-1]["text"].lower() != step["text"].lower():
                out.append(step)
        return out[:MAX_STEPS] or generic_plan(task_query)

    def _activity_steps(self, query: str, calls) -> list[tuple[str, str]]:
        items = [it for c in calls if c["name"] in ("search", "search_activities") for it in evidence_items(c["result"])]
        acts = [it for it in items if it["kind"] in ("activities", "results", "") and it["raw"].get("kind", "activity") == "activity"]
        if not acts:
            return []
        texts = [it["text"] for it in acts]
        sims = self.embedder.encode(texts, kind="passage") @ self.embedder.encode([query], kind="query")[0]
        ranked = [acts[i] for i in np.argsort(-sims, kind="stable")[:2]]
        steps: list[tuple[str, str]] = []
        for it in ranked:
            raw = it["raw"]
            text = str(raw.get("summary") or raw.get("text") or "")
            text = re.sub(r"^\[[^\]]*\]\s*", "", text)
            place = str(raw.get("place") or raw.get("location") or raw.get("environment") or "").replace("_", " ")
            place = re.sub(r"\s*\(.*$", "", place)
            for part in re.split(r"[;.]\s*", text):
                if part.strip():
                    steps.append((part.strip(), place))
        return steps


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
    return [{"action": a, "entity": e, "location": loc, "grounded": False,
             "text": f"{a.capitalize()} the {e} at the {loc}"} for a, e, loc in steps]

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

Planning: `agent.planner` and `agent.compose`. It looks up routines for the goal, the person's
preferences about it and the episodes most like it; for a goal of several actions, routines (or
episodes) for each; then the objects the draft plan needs (search_objects, else
get_object_history, else search). It composes: per action of the goal, a remembered procedure
used as learned or transferred to the goal's object (order kept), procedures chained in the
goal's order, the object fetched first and the tools the person handles for that action taken
up; objects grounded in the person's names and places, or said to be "not in memory"; retrieved
preferences inserted at the steps they govern (`apply_preferences`). Every step keeps the
evidence ids it came from; the answer lists them under the numbered plan.

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
from memora_graph.agent import planner
from memora_graph.agent.planner import task_text, compose_structured, plan_lookups, plan_text
from memora_graph.agent.reading import ReaderDecision, parse_question, score
from memora_graph.embed import get_embedder
from memora_graph.errors import MemoraError
from memora_graph.retrieve.results import ToolResult
from memora_graph.perceive.lexicon import Lexicon

EVIDENCE_PER_CALL = 6  # the best results of each call are read
EVIDENCE_CHARS = 240


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

    def decide(self, view: dict[str, Any], calls: list[dict[str, Any]]) -> ReaderDecision:
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
        goal = task_text(state.view["task_query"])
        if not forced and names:
            calls = plan_lookups(goal, names, state.calls, self.lexicon)
            if calls:
                return PolicyReply(tool_calls=[_call(n, **a) for n, a in calls])
        steps = self.structured_plan(state.view["task_query"], state.calls)
        return PolicyReply(content=plan_text(steps))

    def compose_plan(self, task_query: str, calls: list[dict[str, Any]]) -> list[str]:
        return [s["text"] for s in self.structured_plan(task_query, calls)]

    def structured_plan(self, task_query: str, calls: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """The plan composed from the calls' results (`agent.compose`): procedures adapted and
        chained for the goal's parts, objects grounded, preferences inserted; every step with its
        evidence ids. A plan from the request alone when memory returned no procedure."""
        return compose_structured(task_query, calls, self.lexicon, from_task=planner.TASK_FIRST)

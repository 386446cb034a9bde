"""The ReAct loop shared by every condition and every answer policy (a model or the offline policy).

Budgets (paper, Implementation details): EAM-QA at most 5 iterations, planning
at most 8, one model call per iteration; the last iteration is the forced final answer with tools
disabled (so 4 / 7 tool rounds at most). At most 3 tool calls per response; a call identical to an
earlier one is answered from the first result without running the tool again. A reply with no
tool call, under 30 characters and with no answer marker gets one retry. Conversations over
24,000 characters have their tool results cut to 1,500, then 800 characters.

Memory is reached only through `toolset`, which is bound to the task's target participant.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

from memora_graph.agent import prompts
from memora_graph.agent.toolcalls import ToolCall, canonical_arguments, parse_tool_calls, strip_tool_markup
from memora_graph.retrieve.results import ToolErrorResult, ToolResult

MAX_ITERATIONS = {"eam_qa": 5, "planning": 8}
MAX_CALLS_PER_RESPONSE = 3
CONVERSATION_LIMIT = 24_000
TOOL_CLIPS = (1_500, 800)
TOOL_RESULT_MAX = 6_000
_ANSWER_MARKER = re.compile(r"plan\s*:|answer\s*:|step\s*1|^\s*1[.)]|final answer|\b[A-E]\)", re.I | re.M)


@dataclass
class PolicyReply:
    """What a policy answers for one iteration: text and/or OpenAI-shaped native tool calls."""

    content: str = ""
    tool_calls: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class AgentState:
    """What a policy may know: the task as the agent sees it and the tool calls it made."""

    task_kind: str
    view: dict[str, Any]
    iteration: int = 0
    calls: list[dict[str, Any]] = field(default_factory=list)  # {name, arguments, result: a ToolResult}


class Policy(Protocol):
    name: str

    def respond(self, messages: list[dict[str, Any]], tools: list[dict[str, Any]], *, forced: bool,
                state: AgentState) -> PolicyReply: ...


class Tools(Protocol):
    participant: str

    def schemas(self) -> list[dict[str, Any]]: ...

    def call(self, name: str, arguments: dict[str, Any]) -> ToolResult: ...

    # optional: `prefetch(calls)` with calls = [(name, arguments)] warms whatever the calls of one
    # response share (query embeddings) before they run one by one; counted as tool time



@dataclass
class AgentResult:
    final_text: str
    iterations: int
    forced: bool
    retried: bool
    tool_calls: list[dict[str, Any]]
    model_s: float
    tools_s: float
    total_s: float
    n_messages: int

    @property
    def other_s(self) -> float:
        return max(0.0, self.total_s - self.model_s - self.tools_s)


def as_json(result: Any) -> Any:
    """A tool result as the JSON value an agent sees (typed results through their models)."""
    return result.as_json() if isinstance(result, ToolResult) else result


def _clip_conversation(messages: list[dict[str, Any]]) -> None:
    for limit in TOOL_CLIPS:
        if sum(len(str(m.get("content") or "")) for m in messages) <= CONVERSATION_LIMIT:
            return
        for m in messages:
            if m.get("_tool_result") and len(m["content"]) > limit:
                m["content"] = m["content"][:limit] + " ...[truncated]"


def _public(messages: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in m.items() if not k.startswith("_")} for m in messages]


def _describe(call: ToolCall) -> str:
    return f"{call.name}({canonical_arguments(call.arguments)})"


def run_agent(policy: Policy, toolset: Tools | None, task_kind: str, view: dict[str, Any], prompt_family: str,
              *, max_iterations: int | None = None) -> AgentResult:
    """One episode: an EAM-QA question (view = EamQuestion.answering_view()) or a planning task
    (view = {task_id, participant_id, task_query}). Returns the final reply text and the trace."""
    if task_kind not in MAX_ITERATIONS:
        raise ValueError(f"task_kind must be one of {sorted(MAX_ITERATIONS)}, got {task_kind!r}")
    if toolset is not None and toolset.participant != view["participant_id"]:
        raise ValueError(f"tools are bound to {toolset.participant}, the task is for {view['participant_id']}")
    budget = max_iterations or MAX_ITERATIONS[task_kind]
    tools = toolset.schemas() if toolset is not None else []
    user = prompts.format_question(view) if task_kind == "eam_qa" else prompts.format_task(view)
    messages: list[dict[str, Any]] = [
        {"role": "system", "content": prompts.system_prompt(task_kind, prompt_family)},
        {"role": "user", "content": user},
    ]
    state = AgentState(task_kind, view)
    cache: dict[tuple[str, str], Any] = {}
    trace: list[dict[str, Any]] = []
    made: list[str] = []
    model_s = tools_s = 0.0
    t_start = time.perf_counter()
    forced = retried = False
    final = ""
    iteration = 0
    while iteration < budget:
        forced_now = bool(tools) and iteration == budget - 1
        if forced_now and not forced:
            forced = True
            messages.append({"role": "user", "content": prompts.forced_prompt(task_kind, made)})
        _clip_conversation(messages)
        state.iteration = iteration
        t0 = time.perf_counter()
        reply = policy.respond(_public(messages), [] if forced_now else tools, forced=forced_now or not tools,
                               state=state)
        model_s += time.perf_counter() - t0
        iteration += 1
        calls = [] if (forced_now or not tools) else parse_tool_calls(
            reply.content, reply.tool_calls, available=tools, max_calls=MAX_CALLS_PER_RESPONSE)
        if calls:
            native = bool(reply.tool_calls)
            assistant: dict[str, Any] = {"role": "assistant", "content": reply.content or ""}
            if native:
                assistant["tool_calls"] = [c.to_openai() for c in calls]
            messages.append(assistant)
            text_results = []
            prefetch = getattr(toolset, "prefetch", None)
            if prefetch is not None and len(calls) > 1:  # one batched embedding for the response's queries
                t1 = time.perf_counter()
                try:
                    prefetch([(c.name, dict(c.arguments)) for c in calls if c.key not in cache])
                except Exception:  # a warm-up only; each call still embeds what it needs
                    pass
                tools_s += time.perf_counter() - t1
            for call in calls:
                key = call.key
                duplicate = key in cache
                t1 = time.perf_counter()
                error = None
                if duplicate:
                    result = cache[key]
                else:
                    try:
                        result = toolset.call(call.name, dict(call.arguments))
                    except Exception as exc:  # a tool failure is an observation, not a crash
                        result = ToolErrorResult(error=f"{type(exc).__name__}: {exc}")
                        error = result.error
                    cache[key] = result
                seconds = time.perf_counter() - t1
                tools_s += seconds
                data = as_json(result)
                body = json.dumps(data, ensure_ascii=False, default=str)
                shown = body if not duplicate else json.dumps(
                    {"_duplicate": True, "note": "identical to an earlier call; its result again", "result": data},
                    ensure_ascii=False, default=str)
                shown = shown[:TOOL_RESULT_MAX]
                trace.append({"iteration": iteration, "name": call.name, "arguments": call.arguments,
                              "result_chars": len(body), "duplicate": duplicate, "seconds": round(seconds, 4),
                              "error": error, "format": "native" if native else "text"})
                state.calls.append({"name": call.name, "arguments": call.arguments, "result": result})
                made.append(_describe(call))
                if native:
                    messages.append({"role": "tool", "tool_call_id": call.id, "name": call.name, "content": shown,
                                     "_tool_result": True})
                else:
                    text_results.append(f"<tool_response>\n{shown}\n</tool_response>")
            if text_results:
                messages.append({"role": "user", "content": "\n".join(text_results), "_tool_result": True})
            continue
        final = strip_tool_markup(reply.content)
        premature = len(final) < 30 and not _ANSWER_MARKER.search(final) and not re.fullmatch(r"\W*[A-E]\W*", final)
        if premature and not retried and iteration < budget:
            retried = True
            messages.append({"role": "assistant", "content": reply.content or ""})
            messages.append({"role": "user", "content": prompts.PREMATURE_RETRY[task_kind]})
            continue
        break
    return AgentResult(final_text=final, iterations=iteration, forced=forced, retried=retried, tool_calls=trace,
                       model_s=model_s, tools_s=tools_s, total_s=time.perf_counter() - t_start,
                       n_messages=len(messages))


class ModelPolicy:
    """A chat model behind any registered backend (`openai`, `vllm`, ...), role "answer"."""

    def __init__(self, backend, tags: dict[str, str] | None = None):
        self.backend = backend
        self.name = f"{backend.name}:{backend.model or 'default'}"
        self.tags = tags or {}

    def respond(self, messages, tools, *, forced: bool, state: AgentState) -> PolicyReply:
        kwargs: dict[str, Any] = {}
        if tools:
            # "auto" said out loud: OpenAI and vLLM assume it when tools are given, but
            # llama-cpp-python's server (chatml-function-calling) then leaves the tools out of the
            # prompt and never returns a tool call.
            kwargs["tools"], kwargs["tool_choice"] = tools, "auto"
        tags = {**self.tags, "item": str(state.view.get("question_id") or state.view.get("task_id") or ""),
                "iteration": str(state.iteration)}
        reply = self.backend.chat(messages, role="answer", tags=tags, **kwargs)
        return PolicyReply(content=reply.content or "", tool_calls=list(reply.tool_calls or []))

"""The backend interface: role checks, structured replies with one repair turn, call logging.

A backend implements `_complete` (one request to the model, transport retries included) and, if
it can do better than a thread, `_acomplete`. The rest is here once for every backend: `chat`
and `achat` drive the same conversation plan (`_plan`): ask, validate against the response
model, on failure one repair turn that shows the model its error, then a `ModelReplyError`. Every
call is logged in the `CallLog`, failed ones included."""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any, Generator, Iterable

from pydantic import BaseModel, ConfigDict, Field

from memora_graph.llm.calllog import CallLog, CallRecord, prompt_hash
from memora_graph.llm.errors import ModelReplyError, ModelUnavailableError
from memora_graph.llm.jsonrepair import json_schema_format, repair_messages, validate_reply
from memora_graph.llm.roles import configure_hint


class ChatReply(BaseModel):
    """What `chat` returns: the assistant's text, its native tool calls (OpenAI shape), and the
    validated object when a response_model was given."""

    model_config = ConfigDict(arbitrary_types_allowed=True)

    content: str = ""
    tool_calls: list[dict[str, Any]] = Field(default_factory=list)
    parsed: Any = None
    reasoning: str | None = None
    finish_reason: str | None = None
    model: str | None = None
    usage: dict[str, Any] | None = None
    latency_s: float = 0.0
    retries: int = 0
    repairs: int = 0

    @property
    def message(self) -> dict[str, Any]:
        """The assistant turn to append to the conversation."""
        out: dict[str, Any] = {"role": "assistant", "content": self.content}
        if self.tool_calls:
            out["tool_calls"] = self.tool_calls
        return out



@dataclass
class _Request:
    """One request the conversation plan wants sent (the first ask, or the repair turn)."""

    messages: list[dict[str, Any]]
    tools: list[dict[str, Any]] | None
    tool_choice: str | dict[str, Any] | None
    response_format: dict[str, Any] | None


class Backend:
    """Common behaviour: role checks, structured replies with one repair, call logging.

    Subclasses set `name` and implement `_complete` (and optionally `_acomplete`)."""

    name: str = "?"

    def __init__(self, options: BaseModel, call_log: CallLog | None = None):
        self.options = options
        self.call_log = call_log if call_log is not None else CallLog()

    @property
    def model(self) -> str | None:
        return getattr(self.options, "model", None)

    def supports(self, role: str) -> bool:
        return True

    def require(self, role: str) -> None:
        """Raise ModelUnavailableError before any work starts if this backend cannot do `role`."""
        if not self.supports(role):
            raise ModelUnavailableError(
                f"The {role!r} role needs a model, and the {self.name!r} backend has none: {configure_hint(role)}."
            )

    def chat(
        self,
        messages: list[dict[str, Any]],
        *,
        role: str,
        tools: list[dict[str, Any]] | None = None,
        tool_choice: str | dict[str, Any] | None = None,
        response_model: type[BaseModel] | None = None,
        tags: dict[str, str] | None = None,
    ) -> ChatReply:
        """One model call for `role`. With `response_model`, the reply is validated (one repair
        turn on failure, then ModelReplyError). Every call is logged, failed ones included.
        Safe to call from many threads at once."""
        self.require(role)
        cpu0 = time.thread_time()
        record, started, stats = self._start(messages, role, tags)
        stats.cpu0 = cpu0
        plan = self._plan(messages, role, tools, tool_choice, response_model, stats)
        try:
            request = next(plan)
            while True:
                request = plan.send(self._complete(request.messages, tools=request.tools,
                                                   tool_choice=request.tool_choice,
                                                   response_format=request.response_format, stats=stats))
        except StopIteration as done:
            reply = done.value
        except Exception as exc:
            self._log(record, stats, started, ok=False, error=f"{type(exc).__name__}: {exc}")
            raise
        reply.latency_s = self._log(record, stats, started, ok=True)
        return reply

    async def achat(
        self,
        messages: list[dict[str, Any]],
        *,
        role: str,
        tools: list[dict[str, Any]] | None = None,
        tool_choice: str | dict[str, Any] | None = None,
        response_model: type[BaseModel] | None = None,
        tags: dict[str, str] | None = None,
    ) -> ChatReply:
        """`chat` for asyncio callers: the same plan, repair and logging; requests go through
        `_acomplete` (the async client where a backend has one, else a worker thread)."""
        self.require(role)
        record, started, stats = self._start(messages, role, tags)
        plan = self._plan(messages, role, tools, tool_choice, response_model, stats)
        try:
            request = next(plan)
            while True:
                completion = await self._acomplete(request.messages, tools=request.tools,
                                                   tool_choice=request.tool_choice,
                                                   response_format=request.response_format, stats=stats)
                request = plan.send(completion)
        except StopIteration as done:
            reply = done.value
        except Exception as exc:
            self._log(record, stats, started, ok=False, error=f"{type(exc).__name__}: {exc}")
            raise
        reply.latency_s = self._log(record, stats, started, ok=True)
        return reply

    def _start(self, messages, role, tags) -> tuple[dict, float, "CallStats"]:
        record = dict(
            role=role, backend=self.name, model=self.model, prompt_hash=prompt_hash(messages),
            started_at=datetime.now(timezone.utc).isoformat(timespec="milliseconds"),
            tags={str(k): str(v) for k, v in (tags or {}).items()},
        )
        return record, time.perf_counter(), CallStats()

    def _plan(self, messages, role, tools, tool_choice, response_model,
              stats: "CallStats") -> Generator[_Request, "Completion", ChatReply]:
        """The conversation for one call: yields the requests to send, receives their completions."""
        schema = json_schema_format(response_model) if response_model is not None else None
        completion = yield _Request(messages, tools, tool_choice, schema)
        stats.completions.append(completion)
        parsed = None
        if response_model is not None:
            try:
                parsed = validate_reply(completion.content, response_model)
            except ValueError as first_problem:
                retry = repair_messages(messages, completion.content, str(first_problem))
                completion = yield _Request(retry, tools, tool_choice, schema)
                stats.completions.append(completion)
                try:
                    parsed = validate_reply(completion.content, response_model)
                except ValueError as problem:
                    raise ModelReplyError(
                        f"The {role!r} model ({self.model}) did not return a valid {response_model.__name__} "
                        f"after one repair turn: {problem}. Raw reply: {clip(completion.content, 300)!r}",
                        raw_reply=completion.content, role=role,
                        attempts=[c.content for c in stats.completions],
                    ) from None
        return ChatReply(
            content=completion.content, tool_calls=completion.tool_calls, parsed=parsed,
            reasoning=completion.reasoning, finish_reason=completion.finish_reason,
            model=completion.model or self.model, usage=sum_usage(c.usage for c in stats.completions),
            retries=stats.retries, repairs=len(stats.completions) - 1,
        )

    def _log(self, record: dict, stats: "CallStats", started: float, *, ok: bool, error: str | None = None) -> float:
        latency = time.perf_counter() - started
        usage = sum_usage(c.usage for c in stats.completions) or {}
        model = next((c.model for c in stats.completions if c.model), None) or self.model or record["model"]
        self.call_log.add(CallRecord(
            **{**record, "model": model},
            tokens_in=usage.get("prompt_tokens"), tokens_out=usage.get("completion_tokens"),
            latency_s=round(latency, 6), retries=stats.retries,
            repairs=max(len(stats.completions) - 1, 0), ok=ok, error=clip(error, 500) if error else None,
            server_s=round(stats.server_s, 6) if stats.server_s is not None else None,
            cpu_s=round(time.thread_time() - stats.cpu0, 6) if stats.cpu0 is not None else None,
        ))
        return latency

    def _complete(self, messages, *, tools, tool_choice, response_format, stats: "CallStats") -> "Completion":
        """Send one request (transport retries count into `stats.retries`)."""
        raise NotImplementedError

    async def _acomplete(self, messages, *, tools, tool_choice, response_format, stats: "CallStats") -> "Completion":
        """`_complete` for asyncio callers; by default on a worker thread."""
        return await asyncio.to_thread(self._complete, messages, tools=tools, tool_choice=tool_choice,
                                       response_format=response_format, stats=stats)


@dataclass
class Completion:
    """One completed request to a model (after transport retries)."""

    content: str
    tool_calls: list[dict[str, Any]]
    usage: dict[str, Any] | None
    finish_reason: str | None
    model: str | None
    reasoning: str | None = None


@dataclass
class CallStats:
    """What one `chat` call cost so far; filled in as requests happen, so failures count too."""

    retries: int = 0
    completions: list[Completion] = field(default_factory=list)
    server_s: float | None = None  # time the server says it spent (an X-Server-Time header), summed
    cpu0: float | None = None  # time.thread_time() when a sync call started


def clip(text: str | None, limit: int) -> str:
    text = text or ""
    return text if len(text) <= limit else text[:limit] + f"... ({len(text)} chars)"


def sum_usage(usages: Iterable[dict[str, Any] | None]) -> dict[str, int] | None:
    total: dict[str, int] = {}
    for usage in usages:
        if not usage:
            continue
        for key in ("prompt_tokens", "completion_tokens", "total_tokens"):
            if isinstance(usage.get(key), int):
                total[key] = total.get(key, 0) + usage[key]
    return total or None


class BackendOptions(BaseModel):
    """Base of every backend's options: unknown options are errors."""

    model_config = ConfigDict(extra="forbid")

"""Model backends: the one module that knows how to reach a model.

Every model role (perception, entity editor, consolidation, enrichment, answer agent) calls
`backend.chat(messages, role=...)`. A backend is chosen by name from one registry
(`get_backend("openai", base_url=..., model=...)`) with options validated by a pydantic model.
Each call is logged as a `CallRecord` in a `CallLog`, so cost and latency can be reported per
role and per segment. Structured replies go through one path for every backend: JSON-schema
constrained decoding where the server supports it, JSON extraction, pydantic validation, and
one repair turn that shows the model its error.
"""

from __future__ import annotations

import base64
import functools
import hashlib
import http.client
import importlib
import ipaddress
import json
import os
import re
import socket
import statistics
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterable, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from memora_graph.errors import MemoraError

# ---------------------------------------------------------------------------------------------
# Errors


class ModelError(MemoraError):
    """Base class of everything that goes wrong between us and a model."""


class UnknownBackendError(ModelError):
    """A backend name that is not registered; the message lists the registered ones."""


class BackendOptionsError(ModelError):
    """Options that do not validate for the chosen backend; the message names the option."""


class ModelUnavailableError(ModelError):
    """No model can serve this role: the offline backend, or an optional extra not installed."""


class ModelServerError(ModelError):
    """The server could not be reached or answered with an error; the message names the URL."""

    def __init__(self, message: str, *, url: str, status: int | None = None, body: str | None = None):
        super().__init__(message)
        self.url = url
        self.status = status
        self.body = body


class ModelReplyError(ModelError):
    """The model answered, but not with what was asked for, even after one repair turn."""

    def __init__(self, message: str, *, raw_reply: str, role: str, attempts: list[str] | None = None):
        super().__init__(message)
        self.raw_reply = raw_reply
        self.role = role
        self.attempts = attempts or [raw_reply]


# ---------------------------------------------------------------------------------------------
# Roles (the paper's model registry table, grouped by pipeline role)


@dataclass(frozen=True)
class RoleSpec:
    name: str
    description: str
    default_model: str
    offline_policy: bool  # True when a deterministic policy exists for the offline backend


ROLES: dict[str, RoleSpec] = {
    spec.name: spec
    for spec in (
        RoleSpec("perception", "video segment (frames, audio) to a layered record",
                 "Qwen/Qwen2.5-Omni-7B", offline_policy=False),
        RoleSpec("editor", "online memory processor: ADD / UPDATE / DELETE / NOOP entity edits",
                 "Qwen/Qwen3-30B-A3B-Instruct-2507", offline_policy=True),
        RoleSpec("consolidation", "preferences and procedures from the episodic memory",
                 "Qwen/Qwen3.6-35B-A3B", offline_policy=True),
        RoleSpec("enrichment", "generated preferences with checked supporting evidence",
                 "Qwen/Qwen3.6-35B-A3B", offline_policy=True),
        RoleSpec("answer", "answer agent: EAM-QA and planning over the memory tools",
                 "Qwen/Qwen3.6-35B-A3B", offline_policy=True),
    )
}


def _configure_hint(role: str) -> str:
    model = ROLES[role].default_model if role in ROLES else "MODEL"
    return (f"configure one, e.g. `--backend openai --base-url http://127.0.0.1:8000/v1 "
            f"--model {model}` against a server started with `vllm serve {model}`, "
            f"or `--backend vllm --model {model}` with pip install 'memora-graph[vllm]'")


# ---------------------------------------------------------------------------------------------
# Call log


def prompt_hash(messages: list[dict[str, Any]]) -> str:
    """sha256 of the canonical JSON of the messages (sorted keys, no whitespace)."""
    canonical = json.dumps(messages, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


class CallRecord(BaseModel):
    """One model call as seen by the caller (transport retries and the repair turn included)."""

    role: str
    backend: str
    model: str | None
    prompt_hash: str
    tokens_in: int | None = None
    tokens_out: int | None = None
    latency_s: float
    retries: int = 0  # requests re-sent after 429 / 5xx / timeout / dropped connection
    repairs: int = 0  # repair turns after an invalid structured reply (0 or 1)
    ok: bool
    error: str | None = None
    started_at: str
    tags: dict[str, str] = Field(default_factory=dict)  # caller context, e.g. {"segment": ...}


class CallLog:
    """Collects call records in memory; with `path`, also appends each one as a JSON line."""

    def __init__(self, path: str | Path | None = None):
        self.path = Path(path) if path is not None else None
        self.records: list[CallRecord] = []
        self._lock = threading.Lock()

    def add(self, record: CallRecord) -> None:
        with self._lock:
            self.records.append(record)
            if self.path is not None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                with self.path.open("a", encoding="utf-8") as fh:
                    fh.write(record.model_dump_json() + "\n")

    def write_jsonl(self, path: str | Path, *, append: bool = True) -> Path:
        """Write (or append) every record collected so far as JSON lines."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with self._lock, path.open("a" if append else "w", encoding="utf-8") as fh:
            for record in self.records:
                fh.write(record.model_dump_json() + "\n")
        return path

    @staticmethod
    def read_jsonl(path: str | Path) -> list[CallRecord]:
        path = Path(path)
        out = []
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if not line.strip():
                continue
            try:
                out.append(CallRecord.model_validate_json(line))
            except ValidationError as exc:
                raise ModelError(f"{path}: line {number} is not a call record: {exc}") from exc
        return out

    def summary(self, by: str | Iterable[str] = "role") -> list[dict[str, Any]]:
        return summarize_calls(self.records, by=by)

    def __len__(self) -> int:
        return len(self.records)


def summarize_calls(records: Iterable[CallRecord], by: str | Iterable[str] = "role") -> list[dict[str, Any]]:
    """Group records by record fields or tag keys (e.g. "role", ("segment", "role")).

    One row per group: calls, errors, tokens in / out (sums over records that report them),
    latency total / mean / median in seconds, retries and repairs. Rows are sorted by key.
    """
    keys = (by,) if isinstance(by, str) else tuple(by)
    groups: dict[tuple, list[CallRecord]] = {}
    for record in records:
        data = record.model_dump()
        key = tuple(data[k] if k in data and k != "tags" else record.tags.get(k) for k in keys)
        groups.setdefault(key, []).append(record)
    rows = []
    for key in sorted(groups, key=lambda k: tuple("" if v is None else str(v) for v in k)):
        group = groups[key]
        latencies = [r.latency_s for r in group]
        tin = [r.tokens_in for r in group if r.tokens_in is not None]
        tout = [r.tokens_out for r in group if r.tokens_out is not None]
        row: dict[str, Any] = dict(zip(keys, key))
        row.update(
            calls=len(group),
            errors=sum(not r.ok for r in group),
            tokens_in=sum(tin) if tin else None,
            tokens_out=sum(tout) if tout else None,
            latency_total_s=round(sum(latencies), 6),
            latency_mean_s=round(statistics.fmean(latencies), 6),
            latency_median_s=round(statistics.median(latencies), 6),
            retries=sum(r.retries for r in group),
            repairs=sum(r.repairs for r in group),
        )
        rows.append(row)
    return rows


# ---------------------------------------------------------------------------------------------
# Messages: multimodal content parts (passed through to the server unchanged)


def text_part(text: str) -> dict[str, Any]:
    return {"type": "text", "text": text}


def image_part(data: bytes, mime: str = "image/jpeg") -> dict[str, Any]:
    """An image as an OpenAI `image_url` part holding a data: URL."""
    encoded = base64.b64encode(data).decode("ascii")
    return {"type": "image_url", "image_url": {"url": f"data:{mime};base64,{encoded}"}}


def audio_part(data: bytes, fmt: str = "wav") -> dict[str, Any]:
    """Audio as an OpenAI `input_audio` part (base64, format "wav" or "mp3")."""
    return {"type": "input_audio", "input_audio": {"data": base64.b64encode(data).decode("ascii"), "format": fmt}}


# ---------------------------------------------------------------------------------------------
# Structured replies: JSON extraction, validation, repair

_FENCE = re.compile(r"```[ \t]*([\w-]*)[ \t]*\n?(.*?)```", re.DOTALL)
_THINK = re.compile(r"<think>.*?(?:</think>|\Z)", re.DOTALL | re.IGNORECASE)


class _NoJSON(ValueError):
    pass


def extract_json(text: str) -> Any:
    """The JSON value in a model reply: the whole reply, a ```json fence, or the first
    object/array embedded in prose. Raises ValueError when there is none.

    Raw control characters (a newline, a tab) inside strings are accepted (`strict=False`):
    llama-cpp-python's schema grammar lets a small model write them, and nothing else about
    such a reply is wrong."""
    if text is None or not text.strip():
        raise _NoJSON("the reply is empty")
    candidates = [text.strip()]
    without_think = _THINK.sub("", text).strip()
    if without_think != candidates[0]:
        candidates.append(without_think)
    for body in candidates:
        try:
            return json.loads(body, strict=False)
        except json.JSONDecodeError:
            pass
    body = candidates[-1]
    for match in _FENCE.finditer(body):
        try:
            return json.loads(match.group(2).strip(), strict=False)
        except json.JSONDecodeError:
            continue
    decoder = json.JSONDecoder(strict=False)
    for match in re.finditer(r"[\[{]", body):
        try:
            value, _ = decoder.raw_decode(body, match.start())
        except json.JSONDecodeError:
            continue
        if isinstance(value, (dict, list)):
            return value
    raise _NoJSON("the reply contains no JSON object")


def _validate_reply(text: str, response_model: type[BaseModel]) -> BaseModel:
    """Parse and validate; raises ValueError with a message meant for the model to read."""
    try:
        value = extract_json(text)
    except _NoJSON as exc:
        raise ValueError(f"{exc}; reply with one JSON object and nothing else") from None
    try:
        return response_model.model_validate(value)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err['loc']) or '(root)'}: {err['msg']}" for err in exc.errors()[:10]
        )
        raise ValueError(f"the JSON does not match the schema: {problems}") from None


def json_schema_format(response_model: type[BaseModel]) -> dict[str, Any]:
    """The OpenAI `response_format` for JSON-schema constrained decoding (vLLM supports it)."""
    return {
        "type": "json_schema",
        "json_schema": {"name": response_model.__name__, "schema": json.loads(_schema_json(response_model))},
    }


@functools.lru_cache(maxsize=256)
def _schema_json(response_model: type[BaseModel]) -> str:
    # Generating a pydantic schema costs ~25 ms for a nested record: once per model, not per call.
    return json.dumps(response_model.model_json_schema())


def repair_messages(messages: list[dict[str, Any]], bad_reply: str, problem: str) -> list[dict[str, Any]]:
    """The conversation for the one repair turn: the model sees its reply and what is wrong."""
    return [
        *messages,
        {"role": "assistant", "content": bad_reply},
        {"role": "user", "content": (
            f"Your previous reply could not be used: {problem}. "
            "Reply again with only the corrected JSON object, matching the required schema."
        )},
    ]


# ---------------------------------------------------------------------------------------------
# Backends


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
class _Completion:
    """One completed request to a model (after transport retries)."""

    content: str
    tool_calls: list[dict[str, Any]]
    usage: dict[str, Any] | None
    finish_reason: str | None
    model: str | None
    reasoning: str | None = None


@dataclass
class _CallStats:
    """What one `chat` call cost so far; filled in as requests happen, so failures count too."""

    retries: int = 0
    completions: list[_Completion] = field(default_factory=list)


class Backend:
    """Common behaviour: role checks, structured replies with one repair, call logging.

    Subclasses set `name` and implement `_complete`."""

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
                f"The {role!r} role needs a model, and the {self.name!r} backend has none: {_configure_hint(role)}."
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
        turn on failure, then ModelReplyError). Every call is logged, failed ones included."""
        self.require(role)
        started = time.perf_counter()
        record = dict(
            role=role, backend=self.name, model=self.model, prompt_hash=prompt_hash(messages),
            started_at=datetime.now(timezone.utc).isoformat(timespec="milliseconds"),
            tags={str(k): str(v) for k, v in (tags or {}).items()},
        )
        stats = _CallStats()
        try:
            reply = self._chat(messages, role, tools, tool_choice, response_model, stats)
        except Exception as exc:
            self._log(record, stats, started, ok=False, error=f"{type(exc).__name__}: {exc}")
            raise
        reply.latency_s = self._log(record, stats, started, ok=True)
        return reply

    def _chat(self, messages, role, tools, tool_choice, response_model, stats: _CallStats) -> ChatReply:
        schema = json_schema_format(response_model) if response_model is not None else None
        completion = self._complete(messages, tools=tools, tool_choice=tool_choice, response_format=schema, stats=stats)
        stats.completions.append(completion)
        parsed = None
        if response_model is not None:
            try:
                parsed = _validate_reply(completion.content, response_model)
            except ValueError as first_problem:
                retry = repair_messages(messages, completion.content, str(first_problem))
                completion = self._complete(retry, tools=tools, tool_choice=tool_choice, response_format=schema,
                                            stats=stats)
                stats.completions.append(completion)
                try:
                    parsed = _validate_reply(completion.content, response_model)
                except ValueError as problem:
                    raise ModelReplyError(
                        f"The {role!r} model ({self.model}) did not return a valid {response_model.__name__} "
                        f"after one repair turn: {problem}. Raw reply: {_clip(completion.content, 300)!r}",
                        raw_reply=completion.content, role=role,
                        attempts=[c.content for c in stats.completions],
                    ) from None
        return ChatReply(
            content=completion.content, tool_calls=completion.tool_calls, parsed=parsed,
            reasoning=completion.reasoning, finish_reason=completion.finish_reason,
            model=completion.model or self.model, usage=_sum_usage(c.usage for c in stats.completions),
            retries=stats.retries, repairs=len(stats.completions) - 1,
        )

    def _log(self, record: dict, stats: _CallStats, started: float, *, ok: bool, error: str | None = None) -> float:
        latency = time.perf_counter() - started
        usage = _sum_usage(c.usage for c in stats.completions) or {}
        model = next((c.model for c in stats.completions if c.model), None) or self.model or record["model"]
        self.call_log.add(CallRecord(
            **{**record, "model": model},
            tokens_in=usage.get("prompt_tokens"), tokens_out=usage.get("completion_tokens"),
            latency_s=round(latency, 6), retries=stats.retries,
            repairs=max(len(stats.completions) - 1, 0), ok=ok, error=_clip(error, 500) if error else None,
        ))
        return latency

    def _complete(self, messages, *, tools, tool_choice, response_format, stats: _CallStats) -> _Completion:
        """Send one request (transport retries count into `stats.retries`)."""
        raise NotImplementedError


def _clip(text: str | None, limit: int) -> str:
    text = text or ""
    return text if len(text) <= limit else text[:limit] + f"... ({len(text)} chars)"


def _sum_usage(usages: Iterable[dict[str, Any] | None]) -> dict[str, int] | None:
    total: dict[str, int] = {}
    for usage in usages:
        if not usage:
            continue
        for key in ("prompt_tokens", "completion_tokens", "total_tokens"):
            if isinstance(usage.get(key), int):
                total[key] = total.get(key, 0) + usage[key]
    return total or None


class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid")


# -- offline ------------------------------------------------------------------------------------


class OfflineOptions(_Options):
    pass


class OfflineBackend(Backend):
    """No model. Callers run the deterministic policy of a role when `supports(role)` is True;
    roles without one (video perception) fail up front with instructions."""

    name = "offline"

    def supports(self, role: str) -> bool:
        return role in ROLES and ROLES[role].offline_policy

    def chat(self, messages, *, role: str, **_: Any) -> ChatReply:
        self.require(role)
        raise ModelUnavailableError(
            f"The offline backend cannot answer free-form prompts (role {role!r}); callers run the "
            f"deterministic {role} policy instead. To use a model for this role, {_configure_hint(role)}."
        )


# -- openai -------------------------------------------------------------------------------------


class OpenAIOptions(_Options):
    base_url: str = "http://127.0.0.1:8000/v1"
    model: str | None = None  # None: the first model the server lists at GET /models
    api_key: str | None = Field(default_factory=lambda: os.environ.get("OPENAI_API_KEY"))
    timeout_s: float = Field(120.0, gt=0)
    max_retries: int = Field(3, ge=0, le=20)
    backoff_s: float = Field(0.5, ge=0)  # first retry delay; doubles each retry, capped at 30 s
    temperature: float = Field(0.0, ge=0, le=2)
    max_tokens: int | None = Field(2048, gt=0)
    top_p: float | None = Field(None, gt=0, le=1)
    json_schema: bool = True  # send a response_format that carries the reply's JSON schema
    # How the schema is sent: "json_schema" is OpenAI's {"type": "json_schema", "json_schema": {...}}
    # (vLLM, SGLang, llama.cpp's llama-server); "json_object" is {"type": "json_object", "schema": {...}},
    # which llama-cpp-python's server (python -m llama_cpp.server) turns into a grammar and which
    # answers "json_schema" with HTTP 500 "Input should be 'text' or 'json_object'".
    structured_output: Literal["json_schema", "json_object"] = "json_schema"
    extra_body: dict[str, Any] = Field(default_factory=dict)  # e.g. chat_template_kwargs, repetition_penalty

    @field_validator("base_url")
    @classmethod
    def _http_url(cls, value: str) -> str:
        parsed = urllib.parse.urlparse(value)
        if parsed.scheme not in ("http", "https") or not parsed.netloc:
            raise ValueError(f"must be an http(s) URL such as http://127.0.0.1:8000/v1, got {value!r}")
        return value.rstrip("/")


_RETRY_STATUS = {408, 409, 425, 429}


class OpenAIBackend(Backend):
    """Any OpenAI-compatible chat-completions server (vLLM serve, llama.cpp server, hosted APIs)."""

    name = "openai"
    options: OpenAIOptions

    def __init__(self, options: OpenAIOptions, call_log: CallLog | None = None):
        super().__init__(options, call_log)
        self._model = options.model
        host = urllib.parse.urlparse(options.base_url).hostname or ""
        # Loopback servers are never reached through a proxy from the environment.
        handlers = [urllib.request.ProxyHandler({})] if _is_loopback(host) else []
        self._opener = urllib.request.build_opener(*handlers)

    @property
    def model(self) -> str | None:
        return self._model

    def list_models(self) -> list[str]:
        data = self._request("GET", "/models", None, _CallStats())
        try:
            return [str(item["id"]) for item in data["data"]]
        except (KeyError, TypeError) as exc:
            raise ModelServerError(
                f"{self.options.base_url}/models: not an OpenAI model list: {_clip(json.dumps(data), 200)}",
                url=f"{self.options.base_url}/models",
            ) from exc

    def resolve_model(self) -> str:
        if self._model is None:
            models = self.list_models()
            if not models:
                raise ModelServerError(f"{self.options.base_url}/models lists no model; pass --model",
                                       url=f"{self.options.base_url}/models")
            self._model = models[0]
        return self._model

    def _complete(self, messages, *, tools, tool_choice, response_format, stats: _CallStats) -> _Completion:
        opts = self.options
        payload: dict[str, Any] = {"model": self.resolve_model(), "messages": messages, "temperature": opts.temperature}
        if opts.max_tokens is not None:
            payload["max_tokens"] = opts.max_tokens
        if opts.top_p is not None:
            payload["top_p"] = opts.top_p
        if tools:
            payload["tools"] = tools
        if tool_choice is not None:
            payload["tool_choice"] = tool_choice
        if response_format is not None and opts.json_schema:
            payload["response_format"] = _as_structured_output(response_format, opts.structured_output)
        payload.update(opts.extra_body)
        data = self._request("POST", "/chat/completions", payload, stats)
        url = f"{opts.base_url}/chat/completions"
        try:
            choice = data["choices"][0]
            message = choice["message"]
        except (KeyError, IndexError, TypeError):
            raise ModelServerError(f"{url}: the reply is not a chat completion: {_clip(json.dumps(data), 300)}",
                                   url=url) from None
        return _Completion(
            content=_content_text(message.get("content")),
            tool_calls=list(message.get("tool_calls") or []),
            usage=data.get("usage") if isinstance(data.get("usage"), dict) else None,
            finish_reason=choice.get("finish_reason"),
            model=data.get("model") or payload["model"],
            reasoning=message.get("reasoning_content") or message.get("reasoning"),
        )

    def _request(self, method: str, path: str, payload: dict | None, stats: _CallStats) -> Any:
        """Send one request with retries on 429 / 5xx / timeouts / dropped connections."""
        opts = self.options
        url = opts.base_url + path
        body = json.dumps(payload).encode("utf-8") if payload is not None else None
        headers = {"Content-Type": "application/json", "Accept": "application/json"}
        if opts.api_key:
            headers["Authorization"] = f"Bearer {opts.api_key}"
        attempt = 0
        while True:
            request = urllib.request.Request(url, data=body, headers=headers, method=method)
            delay = None
            try:
                with self._opener.open(request, timeout=opts.timeout_s) as response:
                    raw = response.read()
                try:
                    return json.loads(raw)
                except json.JSONDecodeError:
                    raise ModelServerError(f"{url}: the server's reply is not JSON: {_clip(raw.decode('utf-8', 'replace'), 300)!r}",
                                           url=url, body=raw.decode("utf-8", "replace")) from None
            except urllib.error.HTTPError as exc:
                text = exc.read().decode("utf-8", "replace")
                retryable = exc.code in _RETRY_STATUS or exc.code >= 500
                failure = ModelServerError(_http_message(url, exc.code, text, payload), url=url, status=exc.code, body=text)
                if not retryable:
                    raise failure from None
                delay = _retry_after(exc.headers.get("Retry-After"))
            except urllib.error.URLError as exc:
                reason = exc.reason
                if isinstance(reason, ConnectionRefusedError):
                    raise ModelServerError(
                        f"Could not connect to {url}: connection refused. Is the model server running? "
                        f"Start one with `vllm serve MODEL` or pass --base-url.", url=url) from None
                if isinstance(reason, (TimeoutError, socket.timeout)):
                    failure = ModelServerError(f"{url}: no reply within {opts.timeout_s:g} s (timeout_s)", url=url)
                elif isinstance(reason, OSError):
                    failure = ModelServerError(f"{url}: connection failed: {reason}", url=url)
                else:
                    raise ModelServerError(f"{url}: {reason}", url=url) from None
            except (TimeoutError, socket.timeout):
                failure = ModelServerError(f"{url}: no reply within {opts.timeout_s:g} s (timeout_s)", url=url)
            except (ConnectionError, OSError, http.client.HTTPException) as exc:
                # Resets, http.client.RemoteDisconnected, IncompleteRead: the server dropped the connection.
                failure = ModelServerError(f"{url}: the server closed the connection: {exc}", url=url)
            if attempt >= opts.max_retries:
                if opts.max_retries:
                    failure.args = (f"{failure.args[0]} (gave up after {attempt + 1} attempts)",)
                raise failure
            if delay is None:
                delay = min(opts.backoff_s * (2 ** attempt), 30.0)
            time.sleep(delay)
            attempt += 1
            stats.retries += 1


def _as_structured_output(response_format: dict[str, Any], style: str) -> dict[str, Any]:
    """The `response_format` in the form the server takes (option structured_output)."""
    if style == "json_object" and response_format.get("type") == "json_schema":
        return {"type": "json_object", "schema": response_format["json_schema"]["schema"]}
    return response_format


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _retry_after(value: str | None) -> float | None:
    try:
        return min(max(float(value), 0.0), 60.0) if value is not None else None
    except ValueError:
        return None


def _http_message(url: str, status: int, body: str, payload: dict | None) -> str:
    detail = body
    try:
        parsed = json.loads(body)
        err = parsed.get("error", parsed) if isinstance(parsed, dict) else parsed
        detail = err.get("message", body) if isinstance(err, dict) else str(err)
    except (json.JSONDecodeError, AttributeError):
        pass
    message = f"{url}: HTTP {status}: {_clip(str(detail), 400)}"
    if payload and "response_format" in payload and (status == 400 or "response_format" in body):
        # llama-cpp-python's server rejects {"type": "json_schema"} with HTTP 500, not 400.
        message += (" (if this server does not support response_format json_schema, pass "
                    "structured_output=json_object (llama-cpp-python's server) or json_schema=false)")
    if status in (401, 403):
        message += " (check the API key: option api_key or the OPENAI_API_KEY environment variable)"
    if status == 404:
        message += " (check base_url, which usually ends in /v1, and the model name)"
    return message


def _content_text(content: Any) -> str:
    if content is None:
        return ""
    if isinstance(content, str):
        return content
    if isinstance(content, list):  # content parts
        return "".join(p.get("text", "") for p in content if isinstance(p, dict))
    return str(content)


# -- vllm (in-process engine; optional extra) ---------------------------------------------------


class VLLMOptions(_Options):
    model: str
    tensor_parallel_size: int = Field(1, ge=1)
    max_model_len: int = Field(32768, gt=0)
    gpu_memory_utilization: float = Field(0.85, gt=0, le=1)
    temperature: float = Field(0.0, ge=0, le=2)
    max_tokens: int = Field(2048, gt=0)
    top_p: float = Field(1.0, gt=0, le=1)
    chat_template_kwargs: dict[str, Any] = Field(default_factory=dict)  # e.g. {"enable_thinking": false}
    engine_kwargs: dict[str, Any] = Field(default_factory=dict)


# One resident engine per configuration for the whole process, as in the paper's runs.
_ENGINES: dict[tuple, Any] = {}
_ENGINES_LOCK = threading.Lock()


def _import_vllm():
    try:
        return importlib.import_module("vllm")
    except ImportError as exc:
        raise ModelUnavailableError(
            "The 'vllm' backend needs the vllm package, which is not installed: "
            "pip install 'memora-graph[vllm]' (on a machine with a GPU), or serve the model with "
            "`vllm serve MODEL` elsewhere and use --backend openai --base-url http://HOST:8000/v1. "
            f"(import error: {exc})"
        ) from None


class VLLMBackend(Backend):
    """An in-process vLLM engine, loaded on first use and kept resident. Tool calls come back as
    text (Hermes / Gemma formats) for `memora_graph.agent.toolcalls` to parse."""

    name = "vllm"
    options: VLLMOptions

    def __init__(self, options: VLLMOptions, call_log: CallLog | None = None):
        super().__init__(options, call_log)
        self._vllm = _import_vllm()

    def _engine(self):
        o = self.options
        key = (o.model, o.tensor_parallel_size, o.max_model_len, o.gpu_memory_utilization,
               json.dumps(o.engine_kwargs, sort_keys=True))
        with _ENGINES_LOCK:
            if key not in _ENGINES:
                _ENGINES[key] = self._vllm.LLM(
                    model=o.model, tensor_parallel_size=o.tensor_parallel_size, max_model_len=o.max_model_len,
                    gpu_memory_utilization=o.gpu_memory_utilization, **o.engine_kwargs,
                )
            return _ENGINES[key]

    def _sampling(self, response_format):
        o = self.options
        kwargs: dict[str, Any] = dict(temperature=o.temperature, max_tokens=o.max_tokens, top_p=o.top_p)
        if response_format is not None:
            schema = response_format["json_schema"]["schema"]
            params = importlib.import_module("vllm.sampling_params")
            if hasattr(params, "StructuredOutputsParams"):  # vLLM >= 0.11
                kwargs["structured_outputs"] = params.StructuredOutputsParams(json=schema)
            elif hasattr(params, "GuidedDecodingParams"):
                kwargs["guided_decoding"] = params.GuidedDecodingParams(json=schema)
        return self._vllm.SamplingParams(**kwargs)

    def _complete(self, messages, *, tools, tool_choice, response_format, stats: _CallStats) -> _Completion:
        kwargs: dict[str, Any] = {"use_tqdm": False}
        if tools and tool_choice != "none":
            kwargs["tools"] = tools
        if self.options.chat_template_kwargs:
            kwargs["chat_template_kwargs"] = self.options.chat_template_kwargs
        outputs = self._engine().chat(messages, self._sampling(response_format), **kwargs)
        out = outputs[0]
        generated = out.outputs[0]
        usage = {"prompt_tokens": len(out.prompt_token_ids or []), "completion_tokens": len(generated.token_ids or [])}
        return _Completion(content=generated.text, tool_calls=[], usage=usage,
                           finish_reason=getattr(generated, "finish_reason", None), model=self.options.model)


# ---------------------------------------------------------------------------------------------
# Registry


@dataclass(frozen=True)
class BackendEntry:
    name: str
    factory: Callable[..., Backend]  # factory(options, call_log) -> Backend
    options_model: type[BaseModel]


_REGISTRY: dict[str, BackendEntry] = {}


def register_backend(name: str, factory: Callable[..., Backend], options_model: type[BaseModel],
                     *, replace: bool = False) -> None:
    """Register a backend. `factory(options, call_log)` receives validated options."""
    if name in _REGISTRY and not replace:
        raise ModelError(f"A backend named {name!r} is already registered")
    _REGISTRY[name] = BackendEntry(name, factory, options_model)


def unregister_backend(name: str) -> None:
    _REGISTRY.pop(name, None)


def list_backends() -> list[str]:
    return sorted(_REGISTRY)


def backend_options(name: str) -> type[BaseModel]:
    """The options model of a backend (for CLIs and documentation)."""
    return _entry(name).options_model


def _entry(name: str) -> BackendEntry:
    try:
        return _REGISTRY[name]
    except KeyError:
        raise UnknownBackendError(
            f"Unknown backend {name!r}. Registered backends: {', '.join(list_backends())}"
        ) from None


def get_backend(name: str, *, call_log: CallLog | None = None, **options: Any) -> Backend:
    """The backend `name` with validated options; unknown names and bad options fail clearly."""
    entry = _entry(name)
    try:
        validated = entry.options_model.model_validate(options)
    except ValidationError as exc:
        known = ", ".join(entry.options_model.model_fields)
        problems = "; ".join(
            f"option {'.'.join(str(p) for p in err['loc']) or '(options)'!r}: "
            + ("unknown option" if err["type"] == "extra_forbidden" else err["msg"])
            for err in exc.errors()
        )
        raise BackendOptionsError(
            f"Invalid options for backend {name!r}: {problems}. Options of {name!r}: {known or '(none)'}"
        ) from None
    return entry.factory(validated, call_log)


register_backend("offline", OfflineBackend, OfflineOptions)
register_backend("openai", OpenAIBackend, OpenAIOptions)
register_backend("vllm", VLLMBackend, VLLMOptions)

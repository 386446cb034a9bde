"""The `openai` backend: any OpenAI-compatible chat-completions server (vLLM serve, SGLang,
llama.cpp / llama-cpp-python servers, hosted APIs) through the official `openai` client.

The client does the transport: connection pooling (one pool per backend, shared by every thread
that calls it), timeouts, and retries with exponential backoff on 408 / 409 / 429 / 5xx, timeouts
and dropped connections, honouring the server's Retry-After (up to 60 s). What is ours: the
request we build (JSON-schema `response_format` in the form the server takes, extra_body), the
typed errors that name the URL and the model, and the call accounting (`retries_taken`, the
server's X-Server-Time)."""

from __future__ import annotations

import ipaddress
import json
import os
import re
import threading
import urllib.parse
from typing import Any, Literal

import httpx2
import openai
from pydantic import Field, field_validator

from memora_graph.llm.base import Backend, BackendOptions, CallStats, Completion, clip
from memora_graph.llm.calllog import CallLog
from memora_graph.llm.errors import (
    ModelAuthError, ModelContextLengthError, ModelNotServedError, ModelRateLimitedError, ModelServerDownError,
    ModelServerError, ModelTimeoutError,
)


class OpenAIOptions(BackendOptions):
    base_url: str = "http://127.0.0.1:8000/v1"
    model: str | None = None  # None: the first model the server lists at GET /models
    api_key: str | None = Field(default_factory=lambda: os.environ.get("OPENAI_API_KEY"))
    timeout_s: float = Field(120.0, gt=0)
    # Retries of the openai client: 408 / 409 / 429 / 5xx, timeouts, dropped connections; the delay is
    # the server's Retry-After when it sends one (<= 60 s), else 0.5 s doubling up to 8 s, with jitter.
    max_retries: int = Field(3, ge=0, le=20)
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


SERVER_TIME_HEADER = "x-server-time"  # seconds the server spent on a request, where it says (our loopback servers)


class OpenAIBackend(Backend):
    """Any OpenAI-compatible chat-completions server, sync (`chat`, thread-safe) and asyncio (`achat`)."""

    name = "openai"
    options: OpenAIOptions

    def __init__(self, options: OpenAIOptions, call_log: CallLog | None = None):
        super().__init__(options, call_log)
        self._model = options.model
        self._model_lock = threading.Lock()
        self._client = openai.OpenAI(**self._client_kwargs(async_=False))
        self._aclient: openai.AsyncOpenAI | None = None

    def _client_kwargs(self, *, async_: bool) -> dict[str, Any]:
        o = self.options
        kwargs: dict[str, Any] = dict(
            base_url=o.base_url, api_key=o.api_key or "EMPTY", timeout=o.timeout_s, max_retries=o.max_retries)
        host = urllib.parse.urlparse(o.base_url).hostname or ""
        if _is_loopback(host):  # a loopback server is never reached through a proxy from the environment
            kwargs["http_client"] = (openai.DefaultAsyncHttpxClient if async_ else openai.DefaultHttpxClient)(
                trust_env=False)
        return kwargs

    @property
    def model(self) -> str | None:
        return self._model

    @property
    def url(self) -> str:
        return f"{self.options.base_url}/chat/completions"

    def list_models(self) -> list[str]:
        url = f"{self.options.base_url}/models"
        try:
            page = self._client.models.list()
        except openai.APIError as exc:
            raise self._error(exc, url, None) from None
        try:
            return [str(item.id) for item in page.data]
        except (AttributeError, TypeError) as exc:
            raise ModelServerError(f"{url}: not an OpenAI model list", url=url) from exc

    def resolve_model(self) -> str:
        if self._model is None:
            with self._model_lock:
                if self._model is None:
                    models = self.list_models()
                    if not models:
                        raise ModelServerError(f"{self.options.base_url}/models lists no model; pass --model",
                                               url=f"{self.options.base_url}/models")
                    self._model = models[0]
        return self._model

    # -- one request ----------------------------------------------------------------------------

    def _request(self, messages, tools, tool_choice, response_format) -> dict[str, Any]:
        o = self.options
        kwargs: dict[str, Any] = {"model": self.resolve_model(), "messages": messages, "temperature": o.temperature}
        if o.max_tokens is not None:
            kwargs["max_tokens"] = o.max_tokens
        if o.top_p is not None:
            kwargs["top_p"] = o.top_p
        if tools:
            kwargs["tools"] = tools
        if tool_choice is not None:
            kwargs["tool_choice"] = tool_choice
        if response_format is not None and o.json_schema:
            kwargs["response_format"] = _as_structured_output(response_format, o.structured_output)
        kwargs.update(o.extra_body)
        return kwargs

    # The request goes out through the client's public `post` (its route for any endpoint: the same
    # pool, timeouts, retries and typed errors as `chat.completions.create`), with our body as is.
    # `create` would first walk every message and tool schema through its TypedDict transform,
    # which costs several ms of CPU per agent turn and changes nothing in a plain JSON body.

    def _complete(self, messages, *, tools, tool_choice, response_format, stats: CallStats) -> Completion:
        kwargs = self._request(messages, tools, tool_choice, response_format)
        try:
            raw = self._client.post("/chat/completions", body=kwargs, cast_to=httpx2.Response)
        except openai.APIError as exc:
            stats.retries += self._retries_spent(exc)
            raise self._error(exc, self.url, kwargs) from None
        return self._completion(raw, kwargs, stats)

    async def _acomplete(self, messages, *, tools, tool_choice, response_format, stats: CallStats) -> Completion:
        if self._aclient is None:
            self._aclient = openai.AsyncOpenAI(**self._client_kwargs(async_=True))
        kwargs = self._request(messages, tools, tool_choice, response_format)
        try:
            raw = await self._aclient.post("/chat/completions", body=kwargs, cast_to=httpx2.Response)
        except openai.APIError as exc:
            stats.retries += self._retries_spent(exc)
            raise self._error(exc, self.url, kwargs) from None
        return self._completion(raw, kwargs, stats)

    def _completion(self, raw: httpx2.Response, kwargs: dict[str, Any], stats: CallStats) -> Completion:
        try:  # the client numbers its attempts in this header of the request it finally sent
            stats.retries += int(raw.request.headers.get("x-stainless-retry-count", 0))
        except ValueError:
            pass
        server = raw.headers.get(SERVER_TIME_HEADER)
        if server is not None:
            try:
                stats.server_s = (stats.server_s or 0.0) + float(server)
            except ValueError:
                pass
        try:
            data = json.loads(raw.text)
            choice = data["choices"][0]
            message = choice["message"]
        except json.JSONDecodeError:
            raise ModelServerError(f"{self.url}: the server's reply is not JSON: {clip(raw.text, 300)!r}",
                                   url=self.url, body=raw.text, model=kwargs["model"]) from None
        except (KeyError, IndexError, TypeError):
            raise ModelServerError(f"{self.url}: the reply is not a chat completion: {clip(raw.text, 300)}",
                                   url=self.url, body=raw.text, model=kwargs["model"]) from None
        return Completion(
            content=_content_text(message.get("content")),
            tool_calls=list(message.get("tool_calls") or []),
            usage=data.get("usage") if isinstance(data.get("usage"), dict) else None,
            finish_reason=choice.get("finish_reason"),
            model=data.get("model") or kwargs["model"],
            reasoning=message.get("reasoning_content") or message.get("reasoning"),
        )

    # -- errors ---------------------------------------------------------------------------------

    def _retries_spent(self, exc: openai.APIError) -> int:
        """Retries the client made before raising `exc` (it retries only these kinds)."""
        status = getattr(exc, "status_code", None)
        retried = isinstance(exc, (openai.APITimeoutError, openai.APIConnectionError)) or (
            status is not None and (status in (408, 409, 429) or status >= 500))
        return self.options.max_retries if retried else 0

    def _error(self, exc: openai.APIError, url: str, kwargs: dict[str, Any] | None) -> ModelServerError:
        model = (kwargs or {}).get("model") or self._model
        who = f"model {model!r} at {url}" if model else url
        attempts = self.options.max_retries + 1
        gave_up = f" (gave up after {attempts} attempts)" if self._retries_spent(exc) else ""
        if isinstance(exc, openai.APITimeoutError):
            return ModelTimeoutError(f"{url}: no reply within {self.options.timeout_s:g} s (timeout_s) from "
                                     f"model {model!r}{gave_up}", url=url, model=model)
        if isinstance(exc, openai.APIConnectionError):
            cause = _root_cause(exc)
            if isinstance(cause, ConnectionRefusedError) or "refused" in str(cause).lower():
                return ModelServerDownError(
                    f"Could not connect to {url}: connection refused{gave_up}. Is the model server running? "
                    f"Start one with `vllm serve {model or 'MODEL'}` or pass --base-url.", url=url, model=model)
            return ModelServerDownError(f"{url}: the connection failed or the server closed it: {cause}{gave_up}",
                                        url=url, model=model)
        if isinstance(exc, openai.APIStatusError):
            status = exc.status_code
            body = exc.response.text if exc.response is not None else ""
            detail = _detail(body)
            message = f"{url}: HTTP {status}: {clip(detail, 400)} (model {model!r}){gave_up}"
            if kwargs and "response_format" in kwargs and (status == 400 or "response_format" in body):
                # llama-cpp-python's server rejects {"type": "json_schema"} with HTTP 500, not 400.
                message += (" (if this server does not support response_format json_schema, pass "
                            "structured_output=json_object (llama-cpp-python's server) or json_schema=false)")
            if status in (401, 403):
                return ModelAuthError(message + " (the server refused the API key: check option api_key or the "
                                      "OPENAI_API_KEY environment variable)", url=url, status=status, body=body, model=model)
            if _CONTEXT.search(detail):
                return ModelContextLengthError(
                    message + f" (the prompt plus max_tokens is longer than the context window of {who}: "
                    "lower max_tokens, shorten the prompt, or serve the model with a longer context)",
                    url=url, status=status, body=body, model=model)
            if status == 404 or (status == 400 and _NOT_SERVED.search(detail)):
                return ModelNotServedError(message + f" (is {model!r} served there? {self._served_hint()}"
                                           "check base_url, which usually ends in /v1)",
                                           url=url, status=status, body=body, model=model)
            if status in (429, 503):
                return ModelRateLimitedError(message + " (the server is rate-limiting or overloaded; lower "
                                             "--concurrency or raise max_retries)",
                                             url=url, status=status, body=body, model=model)
            return ModelServerError(message, url=url, status=status, body=body, model=model)
        return ModelServerError(f"{url}: {type(exc).__name__}: {exc} (model {model!r})", url=url, model=model)

    def _served_hint(self) -> str:
        try:
            served = [m.id for m in self._client.with_options(max_retries=0, timeout=5).models.list().data]
        except Exception:
            return ""
        return f"it serves: {', '.join(served)}; " if served else ""


_CONTEXT = re.compile(r"context length|context window|maximum context|context_length_exceeded|too many tokens|"
                      r"exceeds? the (?:model'?s? )?(?:maximum|context)|prompt is too long|exceed_context", re.I)
_NOT_SERVED = re.compile(r"model.*(does not exist|not found|not served|unknown)|(no such|unknown) model", re.I)


def _root_cause(exc: BaseException) -> BaseException:
    seen = exc
    while seen.__cause__ is not None or seen.__context__ is not None:
        seen = seen.__cause__ or seen.__context__
    return seen


def _detail(body: str) -> str:
    try:
        parsed = json.loads(body)
        err = parsed.get("error", parsed) if isinstance(parsed, dict) else parsed
        if isinstance(err, dict):
            return str(err.get("message", body))
        return str(err)
    except (json.JSONDecodeError, AttributeError):
        return body


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


def _content_text(content: Any) -> str:
    if content is None:
        return ""
    if isinstance(content, str):
        return content
    if isinstance(content, list):  # content parts
        return "".join(p.get("text", "") for p in content if isinstance(p, dict))
    return str(content)

"""A real OpenAI-compatible HTTP server on 127.0.0.1 whose model turns are scripted.

Only the model's words are scripted; the protocol is real (HTTP, JSON bodies, status codes,
delays), so the `openai` backend is tested exactly as it talks to vLLM serve or llama.cpp.

    from memora_graph.testing.scripted_server import ScriptedServer, Turn, tool_call

    def test_something():
        script = [
            Turn(tool_calls=[tool_call("search", {"query": "red mug"})]),   # 1st request
            Turn(status=500),                                               # 2nd: server error
            Turn(content='{"answer": "C"}', usage={"prompt_tokens": 50, "completion_tokens": 5}),
            "plain text reply",                                             # str = Turn(content=...)
        ]
        with ScriptedServer(script) as server:
            backend = get_backend("openai", base_url=server.base_url, model="m", backoff_s=0)
            ...
            assert server.requests[0]["messages"][0]["content"] == "..."

Endpoints: POST /v1/chat/completions answers the next scripted turn (one turn per request,
in order); GET /v1/models lists `models`. Every request is recorded (`server.requests`: the
chat request bodies; `server.headers`: their headers). When the script runs out the server
answers HTTP 410 with a message saying so, and leaving the `with` block raises
AssertionError (unless `strict=False`), so a test cannot pass by accident.
"""

from __future__ import annotations

import hashlib
import json
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

__all__ = ["ScriptedServer", "Turn", "tool_call"]


@dataclass
class Turn:
    """One scripted model turn, i.e. the answer to one POST /v1/chat/completions.

    content     assistant text (may be None when there are tool calls)
    tool_calls  OpenAI-shaped tool calls; build them with `tool_call(name, arguments)`
    usage       the `usage` object to report, e.g. {"prompt_tokens": 10, "completion_tokens": 3};
                omitted from the reply when None
    status      HTTP status; anything but 200 answers an OpenAI-style error body instead
    error       message of that error body
    delay_s     wait this long before answering (to provoke client timeouts)
    raw_body    send exactly these bytes as the 200 body (protocol-level garbage)
    headers     extra response headers, e.g. {"Retry-After": "0"}
    finish_reason  defaults to "tool_calls" when there are tool calls, else "stop"
    """

    content: str | None = None
    tool_calls: list[dict[str, Any]] | None = None
    usage: dict[str, int] | None = None
    status: int = 200
    error: str | None = None
    delay_s: float = 0.0
    raw_body: str | None = None
    headers: dict[str, str] = field(default_factory=dict)
    finish_reason: str | None = None


def tool_call(name: str, arguments: dict[str, Any] | str, id: str | None = None) -> dict[str, Any]:
    """An OpenAI function tool call; `arguments` is JSON-encoded unless already a string."""
    args = arguments if isinstance(arguments, str) else json.dumps(arguments)
    digest = hashlib.sha256(f"{name}:{args}".encode()).hexdigest()[:8]
    return {"id": id or f"call_{digest}", "type": "function",
            "function": {"name": name, "arguments": args}}


class ScriptedServer:
    """Context manager: starts on a free port of 127.0.0.1 in a background thread."""

    def __init__(self, turns: list[Turn | str] | None = None, *, models: tuple[str, ...] = ("scripted-model",),
                 strict: bool = True):
        self._turns: list[Turn] = []
        self.models = list(models)
        self.strict = strict
        self.requests: list[dict[str, Any]] = []  # chat-completion request bodies, in arrival order
        self.headers: list[dict[str, str]] = []  # their HTTP headers
        self.failures: list[str] = []  # requests that found the script empty, or were malformed
        self.served = 0
        self._lock = threading.Lock()
        self._httpd: ThreadingHTTPServer | None = None
        self._port: int | None = None  # kept after stop, so messages naming the URL can be checked
        self._thread: threading.Thread | None = None
        for turn in turns or []:
            self.add(turn)

    # -- script -------------------------------------------------------------------------------

    def add(self, *turns: Turn | str) -> "ScriptedServer":
        with self._lock:
            self._turns.extend(Turn(content=t) if isinstance(t, str) else t for t in turns)
        return self

    @property
    def pending(self) -> int:
        """Scripted turns not yet served."""
        with self._lock:
            return len(self._turns)

    @property
    def base_url(self) -> str:
        """http://127.0.0.1:PORT/v1, the value to give the backend as base_url."""
        if self._port is None:
            raise RuntimeError("ScriptedServer was never started; use it as a context manager")
        return f"http://127.0.0.1:{self._port}/v1"

    @property
    def last_request(self) -> dict[str, Any]:
        return self.requests[-1]

    # -- lifecycle ----------------------------------------------------------------------------

    def start(self) -> "ScriptedServer":
        server = self

        class Handler(_Handler):
            scripted = server

        self._httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._httpd.daemon_threads = True
        self._port = self._httpd.server_address[1]
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.02},
                                        name="scripted-openai", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._thread.join(timeout=5)
            self._httpd = None

    def __enter__(self) -> "ScriptedServer":
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.stop()
        if self.strict and self.failures and exc_type is None:
            raise AssertionError("ScriptedServer: " + " | ".join(self.failures))

    # -- used by the handler ------------------------------------------------------------------

    def _next_turn(self, body: dict[str, Any], headers: dict[str, str]) -> Turn | None:
        with self._lock:
            self.requests.append(body)
            self.headers.append(headers)
            if not self._turns:
                self.failures.append(
                    f"script exhausted: request {len(self.requests)} arrived after all {self.served} "
                    f"scripted turns were served (last message: {_last_message(body)!r})"
                )
                return None
            self.served += 1
            return self._turns.pop(0)


def _last_message(body: dict[str, Any]) -> str:
    try:
        content = body["messages"][-1].get("content")
    except (KeyError, IndexError, TypeError, AttributeError):
        return ""
    text = content if isinstance(content, str) else json.dumps(content)
    return text[:120]


class _Handler(BaseHTTPRequestHandler):
    scripted: ScriptedServer
    protocol_version = "HTTP/1.1"

    def log_message(self, format, *args):  # keep test output quiet
        pass

    def _send(self, status: int, payload: Any, headers: dict[str, str] | None = None, raw: bytes | None = None):
        data = raw if raw is not None else json.dumps(payload).encode("utf-8")
        try:
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            for key, value in (headers or {}).items():
                self.send_header(key, value)
            self.end_headers()
            self.wfile.write(data)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the client gave up (timeout); nothing to answer

    def _error(self, status: int, message: str, headers: dict[str, str] | None = None):
        self._send(status, {"error": {"message": message, "type": "scripted_error", "code": status}}, headers)

    def do_GET(self):
        if self.path.rstrip("/") == "/v1/models":
            data = [{"id": m, "object": "model", "owned_by": "scripted"} for m in self.scripted.models]
            self._send(200, {"object": "list", "data": data})
        else:
            self._error(404, f"no route GET {self.path}")

    def do_POST(self):
        length = int(self.headers.get("Content-Length") or 0)
        raw = self.rfile.read(length)
        if self.path.rstrip("/") != "/v1/chat/completions":
            self._error(404, f"no route POST {self.path}")
            return
        try:
            body = json.loads(raw)
        except json.JSONDecodeError:
            self.scripted.failures.append(f"request body is not JSON: {raw[:120]!r}")
            self._error(400, "request body is not JSON")
            return
        problem = _check_request(body)
        if problem:
            self.scripted.failures.append(f"malformed request: {problem}")
            self._error(400, problem)
            return
        turn = self.scripted._next_turn(body, dict(self.headers.items()))
        if turn is None:
            self._error(410, "scripted server: the script ran out of model turns")
            return
        if turn.delay_s:
            time.sleep(turn.delay_s)
        if turn.status != 200:
            self._error(turn.status, turn.error or f"scripted HTTP {turn.status}", turn.headers)
            return
        if turn.raw_body is not None:
            self._send(200, None, turn.headers, raw=turn.raw_body.encode("utf-8"))
            return
        message: dict[str, Any] = {"role": "assistant", "content": turn.content}
        if turn.tool_calls:
            message["tool_calls"] = turn.tool_calls
        reply: dict[str, Any] = {
            "id": f"chatcmpl-scripted-{self.scripted.served}",
            "object": "chat.completion",
            "created": int(time.time()),
            "model": body["model"],
            "choices": [{
                "index": 0,
                "message": message,
                "finish_reason": turn.finish_reason or ("tool_calls" if turn.tool_calls else "stop"),
            }],
        }
        if turn.usage is not None:
            usage = dict(turn.usage)
            usage.setdefault("total_tokens", usage.get("prompt_tokens", 0) + usage.get("completion_tokens", 0))
            reply["usage"] = usage
        self._send(200, reply, turn.headers)


def _check_request(body: Any) -> str | None:
    """The checks a real server makes before it would run a model."""
    if not isinstance(body, dict):
        return "request body must be a JSON object"
    if not isinstance(body.get("model"), str) or not body["model"]:
        return "'model' is required"
    messages = body.get("messages")
    if not isinstance(messages, list) or not messages:
        return "'messages' must be a non-empty list"
    for i, m in enumerate(messages):
        if not isinstance(m, dict) or m.get("role") not in ("system", "user", "assistant", "tool", "developer"):
            return f"messages[{i}] has no valid role"
    if body.get("stream"):
        return "the scripted server does not stream; send stream=false"
    return None

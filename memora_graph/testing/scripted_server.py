"""A real OpenAI-compatible HTTP server on 127.0.0.1 whose model turns are scripted.

Used by the tests (tests/support re-exports it) and by `memora perf model`, which runs it in a
subprocess (`python -m memora_graph.testing.scripted_server --responder agent --latency 0.5`).

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
            backend = get_backend("openai", base_url=server.base_url, model="m", max_retries=0)
            ...
            assert server.requests[0]["messages"][0]["content"] == "..."

Endpoints: POST /v1/chat/completions answers the next scripted turn (one turn per request,
in order), or, with `responder=`, the turn `responder(request_body)` returns (a pure function of
the request, so many requests can be in flight in any order); GET /v1/models lists `models`;
GET /v1/_stats reports requests served and requests in flight (time-weighted mean, max).
`latency_s` (+- `jitter` as a fraction) delays every reply like a model would, and
`max_concurrency` makes requests beyond it queue, like a server's batch slots. Every reply
carries X-Server-Time: the seconds the server held the request. Every request is recorded (`server.requests`: the
chat request bodies; `server.headers`: their headers). When the script runs out the server
answers HTTP 410 with a message saying so, and leaving the `with` block raises
AssertionError (unless `strict=False`), so a test cannot pass by accident.
"""

from __future__ import annotations

import hashlib
import json
import random
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Callable

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
                 strict: bool = True, responder: Callable[[dict[str, Any]], Turn | str] | None = None,
                 latency_s: float = 0.0, jitter: float = 0.0, max_concurrency: int | None = None,
                 seed: int = 0):
        self._turns: list[Turn] = []
        self.responder = responder
        self.latency_s = latency_s
        self.jitter = jitter
        self._random = random.Random(seed)
        self._slots = threading.BoundedSemaphore(max_concurrency) if max_concurrency else None
        self.arrivals: list[float] = []  # time.monotonic() of each chat request's arrival
        self._inflight = 0
        self._inflight_max = 0
        self._inflight_area = 0.0  # integral of requests-in-flight over time while any is in flight
        self._busy_s = 0.0
        self._last_change: float | None = None
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

    # -- lifecycle ----------------------------------------------------------------------------

    def start(self) -> "ScriptedServer":
        server = self

        class Handler(_Handler):
            scripted = server

        self._httpd = _Server(("127.0.0.1", 0), Handler)
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

    def stats(self) -> dict[str, Any]:
        """Requests served and requests in flight (mean over the time any was in flight, max)."""
        with self._lock:
            return {"requests": len(self.requests), "inflight_max": self._inflight_max,
                    "inflight_mean": round(self._inflight_area / self._busy_s, 3) if self._busy_s else 0.0,
                    "busy_s": round(self._busy_s, 3)}

    def reset_stats(self) -> dict[str, Any]:
        """The stats so far, then start counting afresh (requests in flight stay counted)."""
        out = self.stats()
        with self._lock:
            self.requests.clear()
            self.headers.clear()
            self.arrivals.clear()
            self._inflight_max = self._inflight
            self._inflight_area = self._busy_s = 0.0
        return out

    def _track(self, delta: int) -> None:
        with self._lock:
            now = time.monotonic()
            if self._last_change is not None and self._inflight:
                self._inflight_area += self._inflight * (now - self._last_change)
                self._busy_s += now - self._last_change
            self._last_change = now
            self._inflight += delta
            self._inflight_max = max(self._inflight_max, self._inflight)

    def _delay(self) -> float:
        if not self.latency_s:
            return 0.0
        with self._lock:
            return max(0.0, self.latency_s * (1 + self.jitter * (2 * self._random.random() - 1)))

    def _next_turn(self, body: dict[str, Any], headers: dict[str, str]) -> Turn | None:
        if self.responder is not None:
            turn = self.responder(body)
            with self._lock:
                self.arrivals.append(time.monotonic())
                self.requests.append(body)
                self.headers.append(headers)
                self.served += 1
            return Turn(content=turn) if isinstance(turn, str) else turn
        with self._lock:
            self.arrivals.append(time.monotonic())
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


class _Server(ThreadingHTTPServer):
    request_queue_size = 256  # many clients connect at once (the default backlog of 5 stalls them)
    daemon_threads = True


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
        if self.path.rstrip("/") == "/v1/_stats":
            self._send(200, self.scripted.stats())
        elif self.path.rstrip("/") == "/v1/_stats/reset":
            self._send(200, self.scripted.reset_stats())
        elif self.path.rstrip("/") == "/v1/models":
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
        scripted = self.scripted
        if scripted._slots is not None:
            scripted._slots.acquire()
        started = time.perf_counter()
        scripted._track(+1)
        try:
            self._answer(body, started)
        finally:
            scripted._track(-1)
            if scripted._slots is not None:
                scripted._slots.release()

    def _answer(self, body: dict[str, Any], started: float) -> None:
        turn = self.scripted._next_turn(body, dict(self.headers.items()))
        if turn is None:
            self._error(410, "scripted server: the script ran out of model turns")
            return
        delay = turn.delay_s or self.scripted._delay()
        if delay:
            time.sleep(delay)
        turn = Turn(**{**turn.__dict__, "headers": {
            **turn.headers, "X-Server-Time": f"{time.perf_counter() - started:.6f}"}})
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


def main(argv: list[str] | None = None) -> None:
    """Serve on 127.0.0.1 until killed; prints `PORT <n>` once listening (for `memora perf model`)."""
    import argparse
    import importlib
    import sys

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--responder", default="memora_graph.testing.responders:agent",
                        help="module:function that turns a request body into a Turn")
    parser.add_argument("--latency", type=float, default=0.5)
    parser.add_argument("--jitter", type=float, default=0.2)
    parser.add_argument("--max-concurrency", type=int, default=64)
    parser.add_argument("--model", default="scripted-model")
    args = parser.parse_args(argv)
    module, _, func = args.responder.partition(":")
    responder = getattr(importlib.import_module(module), func)
    server = ScriptedServer(responder=responder, latency_s=args.latency, jitter=args.jitter,
                            max_concurrency=args.max_concurrency, models=(args.model,), strict=False)
    server.start()
    print(f"PORT {server._port}", flush=True)
    try:
        sys.stdin.read()  # until the parent closes our stdin (or kills us)
    finally:
        server.stop()


if __name__ == "__main__":
    main()

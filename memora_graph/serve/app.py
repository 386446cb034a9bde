"""A `MemoryService` on the wire: an MCP server (the official `mcp` SDK's low-level `Server`, so
the tool schemas are the registry's, not derived from Python signatures) over stdio or
streamable HTTP.

Errors: a call to a tool the server does not have, or with arguments its schema refuses, is a
JSON-RPC error (-32602, invalid params) whose message names each field at fault (its `data`
lists them); a call the tool cannot answer (an unknown video, a refused Cypher statement, a
damaged database) is a tool result with `isError` and the reason in words, which an agent reads
and acts on.
"""

from __future__ import annotations

import asyncio
import json
import socket
from importlib.metadata import PackageNotFoundError, version

import anyio
import mcp_types as types
from mcp.server.lowlevel import Server
from mcp.shared.exceptions import MCPError

from memora_graph.errors import MemoraError
from memora_graph.serve.service import ArgumentError, MemoryService, UnknownTool

READ_ONLY = types.ToolAnnotations(read_only_hint=True, destructive_hint=False, idempotent_hint=True,
                                  open_world_hint=False)
WRITES = types.ToolAnnotations(read_only_hint=False, destructive_hint=False, idempotent_hint=True,
                               open_world_hint=False)
HTTP_PATH = "/mcp"


def _version() -> str:
    try:
        return version("memora-graph")
    except PackageNotFoundError:
        return ""


def instructions(service: MemoryService) -> str:
    who = (f"Every tool reads the memory of {service.participant}." if service.participant else
           f"Every call names whose memory it reads with `participant` (one of {', '.join(service.participants)}).")
    return ("Embodied action memory of a person (memora-graph): their places, objects and how their state changed, "
            "10 s activity records, routines and preferences. " + who + " Start with `search` or `ask`; "
            "`get_routine_skill` and `get_preferences` before planning; `cypher` and the `query_*` tools read the "
            "graph directly. " + ("`remember` writes what just happened (a narration with its video and time); the "
                                  "next call reads it." if service.writer is not None else "Everything is read-only."))


def build_server(service: MemoryService, output_schemas: bool = False) -> Server:
    """The MCP server of a service: tools/list and tools/call. Results always carry structured
    content (and the same JSON as text); `output_schemas` also advertises each tool's result
    schema. Off by default: a client that validates results against it (the `mcp` SDK's does, in
    pure-Python jsonschema) spends several times the call itself on it (`memora perf serve
    --output-schemas`; docs/findings/model-backed-runs.md)."""
    tools = [types.Tool(name=e.name, description=e.description, input_schema=e.input_schema,
                        output_schema=e.output_schema if output_schemas else None,
                        annotations=WRITES if e.kind == "remember" else READ_ONLY)
             for e in service.endpoints()]

    async def on_list_tools(ctx, params) -> types.ListToolsResult:
        return types.ListToolsResult(tools=tools)

    async def on_call_tool(ctx, params: types.CallToolRequestParams) -> types.CallToolResult:
        try:
            result = await answer(service, params.name, params.arguments)
        except UnknownTool as exc:
            raise MCPError(types.INVALID_PARAMS, str(exc), data={"tool": params.name}) from None
        except ArgumentError as exc:
            raise MCPError(types.INVALID_PARAMS, str(exc), data={"tool": exc.tool, "fields": exc.fields()}) from None
        except MemoraError as exc:
            return types.CallToolResult(content=[types.TextContent(type="text", text=str(exc))], is_error=True)
        text = json.dumps(result, ensure_ascii=False)
        return types.CallToolResult(content=[types.TextContent(type="text", text=text)], structured_content=result)

    return Server("memora", version=_version(), title="memora-graph memory",
                  instructions=instructions(service), on_list_tools=on_list_tools, on_call_tool=on_call_tool)


async def answer(service: MemoryService, name: str, arguments: dict | None) -> dict:
    """One call, off the event loop: validated here (bounded inputs: milliseconds), run in a
    thread of its own (serve/budget.py) and awaited up to the service's time budget; past it the
    caller gets CallTimeout and the work is stopped, while other calls go on being served. A
    client that cancels its request stops the work too."""
    if service.call_timeout is None:
        return await anyio.to_thread.run_sync(service.call, name, arguments)
    loop = asyncio.get_running_loop()
    finished = loop.create_future()

    def wake() -> None:  # in the call's thread
        try:
            loop.call_soon_threadsafe(lambda: finished.done() or finished.set_result(None))
        except RuntimeError:  # the loop is gone (the server is stopping)
            pass

    call = service.start(name, arguments, on_done=wake)
    late = None
    try:
        with anyio.move_on_after(service.call_timeout):
            await finished
    finally:  # past the budget, or the client cancelled its request: stop the work
        if not call.done():
            late = service.timed_out(call, name)
    if late is not None:
        raise late
    return call.result()


def serve_stdio(service: MemoryService, output_schemas: bool = False) -> None:
    """Serve over this process's stdin / stdout until the client closes stdin."""
    from mcp.server.stdio import stdio_server

    server = build_server(service, output_schemas)

    async def main() -> None:
        async with stdio_server() as (read, write):
            await server.run(read, write, server.create_initialization_options())

    anyio.run(main)


def listen(host: str, port: int) -> socket.socket:
    """A listening socket (port 0: any free port), so the address printed is the one bound."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    # Accepted connections inherit this. Without it a response written in two parts (headers,
    # body) waits for the client's delayed ACK: every call took 40-48 ms more on loopback.
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise MemoraError(f"cannot listen on {host}:{port} ({exc.strerror or exc})") from exc
    sock.listen(128)
    return sock


MAX_BODY = 4 * 2**20  # bytes of one HTTP request; a 1 MB question still gets the field-level error


class BodyLimit:
    """ASGI middleware: a request body over `limit` bytes gets 413 before the MCP app reads it
    (parsing a huge JSON body on the event loop would hold every client up)."""

    def __init__(self, app, limit: int = MAX_BODY):
        self.app, self.limit = app, limit

    async def _refuse(self, send) -> None:
        body = (f'{{"error": "request too large: at most {self.limit} bytes (free text is capped at 2,000 '
                'characters)"}').encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        length = dict(scope.get("headers") or []).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > self.limit):
            return await self._refuse(send)
        seen = 0
        started = False

        async def counted():
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.limit:
                    raise _TooLarge
            return message

        async def sending(message):
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted, sending)
        except _TooLarge:
            if not started:
                await self._refuse(send)


class _TooLarge(Exception):
    pass


class BearerAuth:
    """ASGI middleware: every HTTP request must carry `Authorization: Bearer TOKEN` (a writable
    server's token, given at start); others get 401 before the MCP app sees them."""

    def __init__(self, app, token: str):
        import hmac

        self.app, self._token, self._eq = app, f"Bearer {token}".encode(), hmac.compare_digest

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            got = dict(scope.get("headers") or []).get(b"authorization", b"")
            if not self._eq(got, self._token):
                body = b'{"error": "unauthorized: this memora server needs Authorization: Bearer <token>"}'
                await send({"type": "http.response.start", "status": 401,
                            "headers": [(b"content-type", b"application/json"), (b"www-authenticate", b"Bearer"),
                                        (b"content-length", str(len(body)).encode())]})
                await send({"type": "http.response.body", "body": body})
                return
        await self.app(scope, receive, send)


def serve_http(service: MemoryService, host: str = "127.0.0.1", port: int = 8765, on_ready=None,
               output_schemas: bool = False, token: str | None = None) -> None:
    """Serve streamable HTTP at http://HOST:PORT/mcp until interrupted. `on_ready(url)` is called
    once the socket is bound (the CLI prints the URL, with the actual port for --port 0). With
    `token`, every request must carry it as a bearer token (a writable server requires one)."""
    import uvicorn

    if service.writer is not None and not token:
        raise MemoraError("a writable server over HTTP needs a bearer token (--token, or MEMORA_SERVE_TOKEN)")
    app = build_server(service, output_schemas).streamable_http_app(streamable_http_path=HTTP_PATH, json_response=True, host=host)
    app = BodyLimit(app)
    if token:
        app = BearerAuth(app, token)
    sock = listen(host, port)
    bound = sock.getsockname()[1]
    shown = f"[{host}]" if ":" in host else host
    if on_ready is not None:
        on_ready(f"http://{shown}:{bound}{HTTP_PATH}")
    config = uvicorn.Config(app, log_level="warning", lifespan="on", access_log=False)
    try:
        uvicorn.Server(config).run(sockets=[sock])
    finally:
        sock.close()

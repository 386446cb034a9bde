"""`memora serve` and `memora perf serve`: parse, call the library, render."""

from __future__ import annotations

import sys

import click

from memora_graph.output import output_options, render


def _recipes() -> list[str]:
    from memora_graph.retrieve.search import RECIPES

    return list(RECIPES)


@click.command("serve")
@click.argument("bank", type=click.Path(file_okay=False))
@click.option("--participant", help="Bind every call to this person's memory (P01). Without it, each call names one "
                                    "with its `participant` argument.")
@click.option("--transport", type=click.Choice(["stdio", "http"]), default="stdio", show_default=True,
              help="stdio: a desktop client starts the server and talks over its stdin / stdout. http: streamable "
                   "HTTP at http://HOST:PORT/mcp.")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="With --transport http: the address to listen on (loopback unless told otherwise).")
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True,
              help="With --transport http: the port (0: any free port; the URL is printed on stderr).")
@click.option("--recipe", type=click.Choice(_recipes()), default="inprocess", show_default=True,
              help="Retrieval variant of the typed tools (see memora_graph/retrieve/search.py).")
@click.option("--output-schemas", is_flag=True,
              help="Also advertise each tool's result JSON schema. Results carry structured JSON either way; a "
                   "client that validates them against the schema (the mcp SDK's does) pays 5-40 ms per call.")
@click.option("--writable", is_flag=True,
              help="Also serve the `remember` tool: this server holds the participant's writer (one per participant; "
                   "others are told it is busy) and reads what was just remembered. Needs --participant; over HTTP, "
                   "a --token. The bank and the participant are created if need be.")
@click.option("--token", envvar="MEMORA_SERVE_TOKEN", metavar="TOKEN",
              help="With --transport http: every request must send `Authorization: Bearer TOKEN` (required with "
                   "--writable; default: $MEMORA_SERVE_TOKEN).")
@click.option("--consolidate-every", type=click.IntRange(min=1), metavar="N",
              help="With --writable: update routines and preferences (incremental consolidation) after every N new "
                   "segments, in the background; readers see the old records or the new, never half.")
@click.pass_context
def serve_cmd(ctx, bank, participant, transport, host, port, recipe, output_schemas, writable, token,
              consolidate_every):
    """Serve a memory bank to agents over the Model Context Protocol (MCP).

    The bank is opened read-only (unless --writable), checked against its integrity record, and
    kept open across calls. Tools: every typed retrieval tool (argument schemas from the tool registry; JSON
    results), `ask` (the typed question reader), `cypher` (one read-only statement through the
    guard of `memora query`) and the named queries as `query_<name>` (`memora queries`). Nothing
    served writes. Bad arguments are MCP errors naming the field.

    \b
    Examples:
      memora serve banks/epic --participant P01                       # stdio, for a desktop client
      memora serve banks/epic --transport http                        # every call names its participant
      memora serve banks/epic --participant P03 --transport http --port 8765
      memora serve banks/epic --transport http --host 0.0.0.0 --port 8765   # reachable from other machines
      memora serve banks/home --participant P01 --writable --consolidate-every 100   # + remember, over stdio
      memora serve banks/home --participant P01 --writable --transport http --token "$(openssl rand -hex 16)"
    \b
    A desktop client (Claude Desktop's claude_desktop_config.json):
      {"mcpServers": {"memora": {"command": "/path/to/.venv/bin/memora",
                                 "args": ["serve", "/path/to/banks/epic", "--participant", "P01"]}}}
    """
    from memora_graph.serve import MemoryService
    from memora_graph.serve.app import serve_http, serve_stdio

    given = [f"--{p}" for p in ("host", "port")
             if ctx.get_parameter_source(p) is not click.core.ParameterSource.DEFAULT]
    if transport == "stdio" and given:
        raise click.UsageError(f"{' and '.join(given)} apply to --transport http")
    if writable and not participant:
        raise click.UsageError("--writable serves one participant's memory: add --participant P01")
    if consolidate_every and not writable:
        raise click.UsageError("--consolidate-every applies with --writable")
    if writable and transport == "http" and not token:
        raise click.UsageError("--writable over HTTP needs --token TOKEN (or MEMORA_SERVE_TOKEN): clients send it as "
                               "`Authorization: Bearer TOKEN`")
    if transport == "http" and host not in ("127.0.0.1", "localhost", "::1") and not token:
        click.echo(f"warning: listening on {host}: the server has no authentication; anyone who can reach this "
                   "port can read this memory", err=True)
    stopped: list[int] = []
    if writable:  # SIGTERM (a client or a supervisor stopping the server) closes the writer cleanly:
        import signal  # uvicorn re-raises the signal after its shutdown, which would skip the close below

        def stop(signum, frame):
            stopped.append(128 + signum)
            raise SystemExit(128 + signum)

        signal.signal(signal.SIGTERM, stop)
    service = MemoryService(bank, participant, recipe=recipe, writable=writable, consolidate_every=consolidate_every)
    who = participant or f"each call names one of {', '.join(service.participants)}"
    try:
        if transport == "stdio":
            click.echo(f"memora serve: {bank} ({who}) on stdio", err=True)
            serve_stdio(service, output_schemas)
        else:
            serve_http(service, host, port, output_schemas=output_schemas, token=token if transport == "http" else None,
                       on_ready=lambda url: click.echo(f"memora serve: {bank} ({who}) at {url}", err=True))
    finally:
        service.close()
        if stopped:  # closed and recorded: leave now (idle worker threads would hold the exit for 10 s)
            import os

            sys.stderr.flush()
            os._exit(stopped[0])


@click.command("serve")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--participant", required=True, help="Whose memory the server serves (P01).")
@click.option("--repeat", type=click.IntRange(min=1), default=20, show_default=True,
              help="Timed calls of each argument set.")
@click.option("--cypher-repeat", type=click.IntRange(min=0), default=3, show_default=True,
              help="Timed calls of the cypher tool (a child process per call: about half a second each).")
@click.option("--output-schemas", is_flag=True,
              help="Time the server with `--output-schemas` (the client then validates every result).")
@output_options
def perf_serve_cmd(bank, participant, repeat, cypher_repeat, output_schemas, fmt):
    """Warm tool-call latency of `memora serve` over streamable HTTP on loopback.

    Starts `memora serve BANK --participant P --transport http --port 0` as a child process,
    connects with the `mcp` SDK's client, calls every tool once to warm it, then times each
    call (client-side: request to parsed result) and prints p50 / p95 per tool, next to the same
    calls made in process (no protocol), so the protocol's share shows.

    \b
    Examples:
      memora perf serve banks/epic --participant P01
      memora perf serve banks/epic --participant P03 --repeat 50 --json
      memora perf serve banks/epic --participant P01 --output-schemas
    """
    from memora_graph.serve.perf import run_perf

    report = run_perf(bank, participant, repeat=repeat, cypher_repeat=cypher_repeat, output_schemas=output_schemas)
    click.echo(render(report.frame, fmt))
    if fmt == "table":
        for line in report.summary:
            click.echo(line)

"""`memora serve`: parse, call the library, render."""

from __future__ import annotations

import sys

import click

from memora_graph.cli.form import checkpoint_options, checkpoint_policy


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
@click.option("--unconfined-cypher", is_flag=True,
              help="Offer the cypher tool even where the kernel cannot confine its query process (no Landlock): "
                   "then only the read guard keeps it from the files on disk. The mode in force on this machine is "
                   "printed when the server starts, and by `memora verify`.")
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
@click.option("--call-timeout", type=click.FloatRange(min=0, min_open=True, max=3600), default=10.0,
              show_default=True, metavar="SECONDS",
              help="Time budget of one tool call: past it the call is answered 'took too long' and its work is "
                   "stopped, while other clients go on being served (a remember is left to finish; a cypher call's "
                   "`timeout` is capped at it).")
@checkpoint_options
@click.pass_context
def serve_cmd(ctx, bank, participant, transport, host, port, recipe, output_schemas, unconfined_cypher, writable, token,
              consolidate_every, call_timeout, checkpoint_mb, checkpoint_moments, checkpoint_seconds):
    """Serve a memory bank to agents over the Model Context Protocol (MCP).

    The bank is opened read-only (unless --writable), checked against its integrity record, and
    kept open across calls. Tools: every typed retrieval tool (argument schemas from the tool registry; JSON
    results), `ask` (the typed question reader), `cypher` (one read-only statement through the
    guard of `memora query`, in a process the kernel confines to that one database: offered only
    where Landlock is available, unless --unconfined-cypher; at most 2 run at once) and the named queries as `query_<name>` (`memora queries`). Nothing
    served writes. Bad arguments are MCP errors naming the field. Every call runs off the server's
    event loop under a time budget (--call-timeout); free text (question, query, goal) is at most
    2,000 characters.

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
    given_checkpoint = [f"--{p.replace('_', '-')}" for p in ("checkpoint_mb", "checkpoint_moments", "checkpoint_seconds")
                        if ctx.get_parameter_source(p) is not click.core.ParameterSource.DEFAULT]
    if given_checkpoint and not writable:
        raise click.UsageError(f"{' and '.join(given_checkpoint)} apply with --writable")
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
    service = MemoryService(bank, participant, recipe=recipe, unconfined_cypher=unconfined_cypher, writable=writable,
                            consolidate_every=consolidate_every, call_timeout=call_timeout,
                            checkpoint=checkpoint_policy(checkpoint_mb, checkpoint_moments, checkpoint_seconds)
                            if writable else None)
    if not service.confinement.confined:
        click.echo(f"warning: ad-hoc Cypher {service.confinement.describe()}; "
                   + ("the cypher tool is offered anyway (--unconfined-cypher)" if service.cypher_offered
                      else "the cypher tool is not offered (start with --unconfined-cypher to offer it)"), err=True)
    elif writable and not service.cypher_offered:
        click.echo("note: a --writable server holds the database open, so no confined query process can open it: "
                   "the cypher tool is not offered (--unconfined-cypher offers it, guarded, in this process)", err=True)
    who = participant or f"each call names one of {', '.join(service.participants)}"
    try:
        if transport == "stdio":
            click.echo(f"memora serve: {bank} ({who}) on stdio; ad-hoc Cypher {service.confinement.describe()}", err=True)
            serve_stdio(service, output_schemas)
        else:
            serve_http(service, host, port, output_schemas=output_schemas, token=token if transport == "http" else None,
                       on_ready=lambda url: click.echo(f"memora serve: {bank} ({who}) at {url}; ad-hoc Cypher "
                                                       f"{service.confinement.describe()}", err=True))
    finally:
        service.close()
        if stopped:  # closed and recorded: leave now (idle worker threads would hold the exit for 10 s)
            import os

            sys.stderr.flush()
            os._exit(stopped[0])


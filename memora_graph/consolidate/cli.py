"""`memora consolidate`: (re)run offline consolidation and enrichment on an existing bank."""

from __future__ import annotations

import json
import time

import click
import polars as pl

from memora_graph.errors import ConsolidationError, MemoraError, StoreError
from memora_graph.executors.cli import executor_from, executor_options
from memora_graph.output import output_options, render

_MODEL_OPTIONS = ("backend", "base_url", "model", "enrichment_model", "api_key")


@click.command("consolidate")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--participants", default="all", show_default=True, help="Comma-separated ids (P01,P02) or 'all'.")
@click.option("--processor", default="deterministic", show_default=True,
              help="'deterministic' (CPU rules, no model) or 'llm' (a model answers; needs --backend openai or vllm).")
@click.option("--backend", type=click.Choice(["offline", "openai", "vllm"]), default=None,
              help="With --processor llm: 'openai' is any OpenAI-compatible server (vllm serve, llama.cpp; the "
                   "default), 'vllm' an in-process engine. 'offline' has no model.")
@click.option("--base-url", help="With --backend openai: the server (default http://127.0.0.1:8000/v1).")
@click.option("--model", help="The consolidation model (default: the first model the server lists).")
@click.option("--enrichment-model", help="A different model for enrichment (default: --model).")
@click.option("--api-key", help="With --backend openai: the API key (default: $OPENAI_API_KEY).")
@click.option("-o", "--option", "options", type=(str, str), multiple=True, metavar="NAME VALUE",
              help="With --processor llm: any other backend option (JSON if it parses), e.g. "
                   "-o structured_output json_object for llama-cpp-python's server. Repeatable.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@executor_options
@output_options
def consolidate_cmd(bank, participants, processor, backend, base_url, model, enrichment_model, api_key, options, quiet,
                    executor, ray_address, retries, ray_shared, fmt):
    """Re-run offline consolidation and enrichment on an existing bank.

    Each participant's routines and preferences are replaced in one transaction (a failed or
    killed run leaves the previous ones), and the manifest records which processor made them.
    With --processor llm every model call is recorded in the bank: `memora stats BANK --calls`
    shows the consolidation and enrichment roles, `--calls failed` the calls that failed. A step
    whose reply stays invalid after one repair turn adds nothing (and is reported); evidence ids
    a model invents are dropped, and a routine or preference left without evidence is not written.

    \b
    Examples:
      memora consolidate banks/epic --participants P01,P02
      vllm serve Qwen/Qwen3.6-35B-A3B --port 8000          # on a machine with a GPU
      memora consolidate banks/epic --participants P01 --processor llm --backend openai \\
          --base-url http://127.0.0.1:8000/v1 --model Qwen/Qwen3.6-35B-A3B
      memora stats banks/epic --participant P01 --calls role
      python -m llama_cpp.server --model MODEL.gguf --chat_format chatml-function-calling
      memora consolidate banks/epic --participants P09 --processor llm -o structured_output json_object
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from memora_graph.bank import Bank
    from memora_graph.consolidate import finish_participant, get_processors, processor_names
    from memora_graph.embed import get_embedder

    if processor not in processor_names():
        raise click.BadParameter(f"no consolidation processor {processor!r}; registered: {', '.join(processor_names())}",
                                 param_hint="'--processor'")
    ex = executor_from(executor, ray_address, retries, ray_shared, base_url)
    base_url = ex.base_urls[0] if ex.base_urls else None  # a list is spread over the Ray tasks
    given = dict(zip(_MODEL_OPTIONS, (backend, base_url, model, enrichment_model, api_key)))
    if processor != "llm":
        extra = [f"--{k.replace('_', '-')}" for k, v in given.items() if v is not None] + (["-o"] if options else [])
        if extra:
            raise click.UsageError(f"{', '.join(extra)} only apply with --processor llm")

    b = Bank(bank)
    data = b.manifest()
    if data.get("mode") == "raw":
        raise MemoraError(f"{bank}: a raw bank (one record per observation) is not consolidated; "
                          "build an edited bank to consolidate")
    known = sorted(data["participants"])
    pids = known if participants.strip().lower() == "all" else [p.strip() for p in participants.split(",") if p.strip()]
    missing = [p for p in pids if p not in data["participants"]]
    if missing:
        raise MemoraError(f"{bank}: no participant {', '.join(missing)} in this bank (has: {', '.join(known) or 'none'})")
    if not pids:
        raise click.UsageError("no participants given")

    progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                        disable=quiet, transient=False)
    task = progress.add_task("consolidating", total=len(pids))

    def on_step(participant: str, step: str) -> None:
        progress.update(task, description=f"{participant} {step}")

    procs = get_processors(processor, options=_llm_options(given, _backend_options(options), on_step)
                           if processor == "llm" else None)
    if processor == "llm":
        from memora_graph.consolidate.llm import check_servers

        for warning in check_servers(procs):
            click.echo(f"warning: {warning}", err=True)
    for p in pids:  # a participant another process holds fails here, before any model call
        try:
            b.open(p, read_only=False).close()
        except StoreError as exc:
            raise MemoraError(f"cannot consolidate {p}: {exc}") from exc

    rows, failed = [], []
    embedder = None if ex.remote else get_embedder(data["embed_model"])
    with progress:
        if ex.remote:  # one Ray task per participant (memora_graph/executors/build.py)
            from memora_graph.executors.build import consolidate_on_ray

            llm = {k: v for k, v in _llm_options(given, _backend_options(options), None).items() if k != "on_step"} \
                if processor == "llm" else None
            for row, lines, calls in consolidate_on_ray(
                    ex, b, pids, processor, llm, on_participant=lambda p: progress.advance(task), on_step=on_step,
                    on_notice=lambda text: click.echo(text, err=True)):
                rows.append(row)
                failed += lines
                if procs.call_log is not None:
                    procs.call_log.records.extend(calls)
        for p in pids if not ex.remote else []:
            progress.update(task, description=f"{p} consolidating")
            t0 = time.perf_counter()
            try:
                knowledge = finish_participant(b, p, embedder, processors=procs)
            except ConsolidationError as exc:
                failed.append(str(exc))
                rows.append({"participant": p, "processor": procs.name, "routines": None, "preferences": None,
                             "dropped_ids": None, "dropped_records": None, "model_calls": None, "failed_steps": None,
                             "status": "unchanged (every model step failed)", "seconds": round(time.perf_counter() - t0, 1)})
                progress.advance(task)
                continue
            rows.append({"participant": p, "processor": procs.name, "routines": len(knowledge.routines),
                         "preferences": len(knowledge.preferences), "dropped_ids": knowledge.dropped_ids,
                         "dropped_records": knowledge.dropped_records, "model_calls": len(knowledge.calls),
                         "failed_steps": len(knowledge.failed_steps), "status": "consolidated",
                         "seconds": round(time.perf_counter() - t0, 1)})
            failed += [f"{p} {s.step}: {s.error}" for s in knowledge.failed_steps]
            progress.advance(task)
        progress.update(task, description="done")
    click.echo(render(pl.DataFrame(rows), fmt))
    if fmt == "table" and procs.call_log is not None:
        calls = procs.call_log.records
        tokens = sum((r.tokens_in or 0) + (r.tokens_out or 0) for r in calls)
        click.echo(f"{len(calls)} model calls ({sum(not r.ok for r in calls)} failed, {tokens} tokens); "
                   f"per role: memora stats {bank} --calls role")
    for line in failed:
        click.echo(f"failed: {line}", err=True)
    if any(r["status"] != "consolidated" for r in rows):
        raise click.ClickException("some participants were left unchanged; see the failures above")


def _llm_options(given: dict, backend_options: dict, on_step) -> dict:
    backend = given["backend"] or "openai"
    if backend == "offline":
        from memora_graph.consolidate.llm import OFFLINE_MESSAGE

        raise click.UsageError(OFFLINE_MESSAGE)
    if backend == "vllm" and not given["model"]:
        raise click.UsageError("--backend vllm loads the model in-process: pass --model NAME")
    if backend != "openai":
        extra = [f"--{k.replace('_', '-')}" for k in ("base_url", "api_key") if given[k]]
        if extra:
            raise click.UsageError(f"{', '.join(extra)} only apply with --backend openai")
    opts = {"backend": backend, "on_step": on_step, "model": given["model"],
            "enrichment_model": given["enrichment_model"]}
    opts.update({k: given[k] for k in ("base_url", "api_key") if given[k]})
    clash = sorted(set(backend_options) & {*opts, "call_log", "limits", "consolidation_model"})
    if clash:
        raise click.UsageError(f"-o {', '.join(clash)}: use the command's own option for it")
    opts.update(backend_options)
    return opts


def _backend_options(pairs) -> dict:
    out = {}
    for key, value in pairs:
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out

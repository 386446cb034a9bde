"""`memora consolidate`: (re)run offline consolidation and enrichment on an existing bank."""

from __future__ import annotations

import click
import polars as pl

from memora_graph.cli.executors import executor_from, executor_options
from memora_graph.cli.options import (
    BACKEND, PROCESSOR, backend_option_pairs, backend_options, output_options, participants_option, progress_bar,
    quiet_option,
)
from memora_graph.output import render

_MODEL_OPTIONS = ("backend", "base_url", "model", "enrichment_model", "api_key")


@click.command("consolidate")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@participants_option()
@click.option("--processor", type=PROCESSOR, default="deterministic", show_default=True,
              help="'deterministic' (CPU rules, no model) or 'llm' (a model answers; needs --backend openai or vllm).")
@click.option("--backend", type=BACKEND, default=None,
              help="With --processor llm: 'openai' is any OpenAI-compatible server (vllm serve, llama.cpp; the "
                   "default), 'vllm' an in-process engine. 'offline' has no model.")
@click.option("--base-url", help="With --backend openai: the server (default http://127.0.0.1:8000/v1).")
@click.option("--model", help="The consolidation model (default: the first model the server lists).")
@click.option("--enrichment-model", help="A different model for enrichment (default: --model).")
@click.option("--api-key", help="With --backend openai: the API key (default: $OPENAI_API_KEY).")
@backend_option_pairs
@click.option("--concurrency", type=int, default=8, show_default=True,
              help="With --processor llm: per-video model calls in flight at once (the bank does not depend on it).")
@click.option("--incremental", is_flag=True,
              help="Update from what was added since the last run (live memory): only the videos whose steps changed "
                   "are consolidated again; what spans videos is recomputed, so the records equal a full run's. "
                   "Deterministic processor only.")
@quiet_option
@executor_options
@output_options
def consolidate_cmd(bank, participants, processor, backend, base_url, model, enrichment_model, api_key, options,
                    concurrency, incremental, quiet, executor, ray_address, retries, ray_shared, fmt):
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
      memora consolidate banks/home --incremental          # after `memora remember`: changed videos only
      vllm serve Qwen/Qwen3.6-35B-A3B --port 8000          # on a machine with a GPU
      memora consolidate banks/epic --participants P01 --processor llm --backend openai \\
          --base-url http://127.0.0.1:8000/v1 --model Qwen/Qwen3.6-35B-A3B
      memora stats banks/epic --participant P01 --calls role
      python -m llama_cpp.server --model MODEL.gguf --chat_format chatml-function-calling
      memora consolidate banks/epic --participants P09 --processor llm -o structured_output json_object
    """
    from memora_graph.bank import Bank
    from memora_graph.consolidate import get_processors
    from memora_graph.consolidate.bank import consolidate_bank, consolidation_targets
    from memora_graph.retrieve.view import persist_bank

    ex = executor_from(executor, ray_address, retries, ray_shared, base_url)
    base_url = ex.base_urls[0] if ex.base_urls else None  # a list is spread over the Ray tasks
    given = dict(zip(_MODEL_OPTIONS, (backend, base_url, model, enrichment_model, api_key)))
    if processor != "llm":
        extra = [f"--{k.replace('_', '-')}" for k, v in given.items() if v is not None] + (["-o"] if options else [])
        if extra:
            raise click.UsageError(f"{', '.join(extra)} only apply with --processor llm")
    b = Bank(bank)
    pids = consolidation_targets(b, participants)
    if incremental:
        if processor != "deterministic" or executor != "local":
            raise click.UsageError("--incremental runs the deterministic processor in this process")
        from memora_graph.consolidate.live import consolidate_bank_incremental

        rows = consolidate_bank_incremental(b, pids)
        persist_bank(b.path, pids)
        click.echo(render(pl.DataFrame(rows), fmt))
        return

    progress = progress_bar(quiet)
    task = progress.add_task("consolidating", total=len(pids))

    def on_step(participant: str, step: str) -> None:
        progress.update(task, description=f"{participant} {step}")

    procs = get_processors(processor, options={**_llm_options(given, backend_options(options), on_step),
                                               "concurrency": concurrency} if processor == "llm" else None)
    if processor == "llm":
        from memora_graph.consolidate.llm import check_servers

        for warning in check_servers(procs):
            click.echo(f"warning: {warning}", err=True)
    with progress:
        if ex.remote:  # one Ray task per participant (memora_graph/executors/build.py)
            from memora_graph.consolidate.bank import consolidate_bank_on_ray

            llm = {k: v for k, v in _llm_options(given, backend_options(options), None).items() if k != "on_step"} \
                if processor == "llm" else None
            done = consolidate_bank_on_ray(ex, b, pids, processor, procs, llm, on_done=lambda p: progress.advance(task),
                                           on_step=on_step, on_notice=lambda text: click.echo(text, err=True))
        else:
            done = consolidate_bank(b, pids, procs, on_participant=lambda p: on_step(p, "consolidating"),
                                    on_done=lambda p: progress.advance(task))
        progress.update(task, description="done")
    persist_bank(b.path, [r["participant"] for r in done.rows if r["status"] == "consolidated"])
    click.echo(render(pl.DataFrame(done.rows), fmt))
    if fmt == "table" and done.calls_line(bank):
        click.echo(done.calls_line(bank))
    for line in done.failed:
        click.echo(f"failed: {line}", err=True)
    if not done.ok:
        raise click.ClickException("some participants were left unchanged; see the failures above")


def _llm_options(given: dict, pairs: dict, on_step) -> dict:
    """The LLM processors' options, checked against the backend's registered options model: a
    backend without a model field has no model to consolidate with; one whose model is required
    needs --model; --base-url / --api-key apply only where the backend takes them."""
    from memora_graph.llm import backend_options as options_model

    backend = given["backend"] or "openai"
    fields = options_model(backend).model_fields
    if "model" not in fields:
        from memora_graph.consolidate.llm import OFFLINE_MESSAGE

        raise click.UsageError(OFFLINE_MESSAGE)
    if fields["model"].is_required() and not given["model"]:
        raise click.UsageError(f"--backend {backend} loads the model in-process: pass --model NAME")
    extra = [f"--{k.replace('_', '-')}" for k in ("base_url", "api_key") if given[k] and k not in fields]
    if extra:
        raise click.UsageError(f"{', '.join(extra)} {'does' if len(extra) == 1 else 'do'} not apply to "
                               f"--backend {backend} (its options: {', '.join(fields)})")
    opts = {"backend": backend, "on_step": on_step, "model": given["model"],
            "enrichment_model": given["enrichment_model"]}
    opts.update({k: given[k] for k in ("base_url", "api_key") if given[k]})
    clash = sorted(set(pairs) & {*opts, "call_log", "limits", "consolidation_model", "concurrency"})
    if clash:
        raise click.UsageError(f"-o {', '.join(clash)}: use the command's own option for it")
    opts.update(pairs)
    return opts

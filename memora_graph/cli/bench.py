"""`memora bench ...`: generate a MEMORA-Bench suite from annotations, validate a release folder."""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

from memora_graph.cli.executors import executor_from, executor_options
from memora_graph.cli.options import (
    ANSWER_POLICY, CONDITIONS, backend_option_pairs, backend_options, output_options, participants_option, progress_bar,
    quiet_option,
)
from memora_graph.errors import MemoraError
from memora_graph.output import render

bench_group = click.Group(
    "bench",
    help="MEMORA-Bench: generate EAM-QA and Planning tasks from action annotations, and validate "
    "release folders (the bundled calibration cohort, a full release, or a generated suite).",
)


@bench_group.command("generate")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write the release layout into (created if missing; files are overwritten).")
@participants_option()
@click.option("--seed", default=42, show_default=True, type=int, help="Seed for every random choice.")
@click.option("--annotations", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="EPIC-style annotation CSV (default: the bundled extension subset).")
@click.option("--no-dedup", is_flag=True, help="Skip the embedding near-duplicate check (exact dedup still applies).")
@click.option("--bank", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="A memory bank whose object registry grounds Replay nouns (enriched_narration, matched_object).")
@click.option("--kind", "suite_kind", type=click.Choice(["suite", "open"]), default="suite", show_default=True,
              help="suite: EAM-QA + Planning (the release layout); open: open questions without choices, "
                   "gold from the annotations, written to OUT/open/pXX.json (see docs/asking.md).")
def generate_cmd(out: Path, participants: list[str] | None, seed: int, annotations: Path | None, no_dedup: bool,
                 bank: Path | None, suite_kind: str) -> None:
    """Generate EAM-QA questions and Planning Replay/Generalize tasks from annotations.

    Writes eam_qa/questions/pXX.json and planning/suites/{replay,generalize}/pXX.json (the
    official layout), planning/audit/replay_filtered/ (tasks above the repeat-rate limit) and
    generation.json, then prints the counts table. No LLM is used; E-correct controls draw
    donor questions from every participant in the annotations.

    \b
    Examples:
      memora bench generate --out runs/bench
      memora bench generate --out runs/bench-p01 --participants P01,P02 --seed 7
      memora bench generate --out runs/bench --annotations EPIC_100_train_subset.csv
      memora bench generate --out runs/bench --bank banks/epic
      memora bench generate --out runs/open --kind open --participants P01,P02,P03
    """
    if suite_kind == "open":
        _generate_open(out, participants, seed, annotations)
        return
    from memora_graph.bench.generate import generate_suite, write_generated
    from memora_graph.bench.validate import ValidationReport, check_suite, count_suite, render_table

    try:
        frame = None
        if annotations is not None:
            from memora_graph.perceive.annotations import load_annotations

            frame = load_annotations(annotations)
        registries = None
        if bank is not None:
            from memora_graph.bank import Bank

            registries = Bank(bank).object_registries(participants)
        suite, report = generate_suite(frame, participants, seed=seed, registries=registries,
                                       embedder=None if no_dedup else "default")
        t0 = time.perf_counter()
        write_generated(suite, report, out)
        seconds = report.seconds + time.perf_counter() - t0
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    table = ValidationReport(str(out), count_suite(suite), check_suite(suite))
    click.echo(render_table(table))
    click.echo(f"\nWrote {out} in {seconds:.1f} s (seed {seed}; near-duplicate check: {report.semantic_dedup}).")


def _generate_open(out: Path, participants: list[str] | None, seed: int, annotations: Path | None) -> None:
    from memora_graph.bench.generate_open import generate_open_files

    try:
        written = generate_open_files(out, participants, seed, annotations)
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    rows = [{"participant": pid, **counts} for pid, counts in written.items()]
    import polars as pl

    click.echo(render(pl.DataFrame(rows), "table"))
    click.echo(f"\nWrote {out / 'open'} (seed {seed}).")


@bench_group.command("open")
@click.argument("bank", type=click.Path(exists=True, file_okay=False, path_type=Path))
@participants_option(default="P01,P02,P03")
@click.option("--questions", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="A folder of open questions (OUT/open from `bench generate --kind open`); default: generated "
                   "now from the bundled annotations with --seed.")
@click.option("--seed", "seeds", default="42", show_default=True,
              help="Seed(s) when generating the questions now: one, or a comma list whose questions are pooled.")
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write every scored item and the summary to this JSON file.")
@click.option("--fit-calibration", "fit_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Fit the answer probability on these participants and write it here (the package's file is "
                   "memora_graph/agent/open_calibration.json).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def open_cmd(bank: Path, participants: list[str] | None, questions: Path | None, seeds: str, out: Path | None,
             fit_path: Path | None, as_json: bool) -> None:
    """Score the open-question reader: answers in the type asked, scored per kind.

    Answers every open question of the participants from BANK (`memora ask` without choices) and
    scores it by type: the place class, the video id, the count within max(1, 20%), yes/no, the
    next action at verb + noun class, "not in memory" for absent subjects and general knowledge.
    Prints accuracy per kind and per wording split (dev / heldout), per operation x scope cell,
    the counterfactual check (questions that differ only in scope: did the answer change where the
    gold did), the expected calibration error of the confidence, and accuracy at 80% and 50%
    coverage. Develop on P01-P03; score others once.

    \b
    Examples:
      memora bench open banks/epic --participants P01,P02,P03
      memora bench open banks/epic --participants P04 --out runs/open-p04.json
      memora bench open banks/epic --participants P01,P02,P03 \\
          --fit-calibration memora_graph/agent/open_calibration.json
    """
    import polars as pl

    from memora_graph.bench.generate_open import generate_open_items
    from memora_graph.bench.open_eval import evaluate_open, fit_calibration, load_items, summarize

    try:
        if participants is None:
            raise click.BadParameter("name the participants to score (develop on P01-P03)", param_hint="'--participants'")
        try:
            seed = [int(x) for x in seeds.split(",") if x.strip()]
        except ValueError:
            raise click.BadParameter(f"{seeds!r}: seeds are integers, comma-separated", param_hint="'--seed'") from None
        if not seed:
            raise click.BadParameter("give at least one seed", param_hint="'--seed'")
        items = load_items(questions, participants) if questions else generate_open_items(participants, seed)
        records = evaluate_open(bank, items)
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    if fit_path is not None:
        cmd = f"memora bench open {bank} --participants {','.join(participants)} --seed {seeds} --fit-calibration {fit_path}"
        fitted = fit_calibration(records, fit_path, participants, cmd)
        from memora_graph.agent.open_calibration import probability

        for r in records:
            r["confidence"] = round(probability(r["answer_kind"], r["features"], fitted["weights"]), 4)
        click.echo(f"Fitted {fit_path} on {len(records)} answers (ECE on the fit cohort {fitted['ece_on_fit']:.3f}).")
    summary = summarize(records)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"participants": participants, "summary": summary, "items": records}, indent=2,
                                  ensure_ascii=False) + "\n")
    if as_json:
        click.echo(json.dumps(summary, indent=2))
        return
    rows = [{"kind": k, **v} for k, v in summary["per_kind"].items()] + \
        [{"kind": f"{k} wording", **v} for k, v in summary["per_split"].items()] + [{"kind": "ALL", **summary["overall"]}]
    click.echo(render(pl.DataFrame(rows), "table"))
    cells = [{"operation x scope": k, **v} for k, v in summary["per_cell"].items()]
    click.echo(render(pl.DataFrame(cells), "table"))
    cf = summary["counterfactual"]
    click.echo(f"counterfactual check: {cf['changed']} of {cf['pairs']} answers changed with their scope where the gold "
               f"did ({cf['rate']})")
    sel = summary["selective"]
    click.echo(f"not-in-memory reason right: {summary['nim_reason_accuracy']}; ECE {summary['ece']:.3f}; accuracy at "
               f"100% / 80% / 50% coverage: {sel['100%']} / {sel['80%']} / {sel['50%']}")


@bench_group.command("validate")
@click.argument("directory", type=click.Path(exists=True, file_okay=False, path_type=Path))
@participants_option()
@click.option("--json", "as_json", is_flag=True, help="Print the counts and problems as JSON.")
def validate_cmd(directory: Path, participants: list[str] | None, as_json: bool) -> None:
    """Check every task file of a release folder and print counts per participant and type.

    Every item is validated (a malformed one is reported with its file, index, id and field),
    metadata counts are checked against the items, and the table gives answerable vs E-correct
    questions per type, Replay tasks (and steps) and Generalize tasks per participant. Exits 1
    when a problem is found.

    \b
    Examples:
      memora bench validate bench/data/memora-bench-calibration
      memora bench validate runs/bench --participants P01,P02
      memora bench validate runs/bench --json
    """
    from memora_graph.bench.validate import render_table, validate_suite

    try:
        report = validate_suite(directory, participants)
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    if as_json:
        click.echo(json.dumps(report.as_dict(), indent=2))
    else:
        click.echo(render_table(report))
    if report.problems:
        raise click.ClickException(f"{len(report.problems)} problem(s) in {directory}")


@bench_group.command("run")
@click.argument("bank", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Run directory (created; an existing run is resumed: finished items are skipped).")
@click.option("--conditions", type=CONDITIONS, default="all", show_default=True,
              help="Comma-separated conditions (no_memory, flat_1d_raw, flat_1d_edited, graph_2d_raw, "
                   "graph_2d_edited, memora_episodic, memora_full) or 'all'.")
@participants_option()
@click.option("--tasks", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="MEMORA-Bench release folder (default: the bundled calibration cohort P01-P04).")
@click.option("--raw-bank", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="A bank built with `memora build DIR --mode raw` (needed by flat_1d_raw and graph_2d_raw).")
@click.option("--episodic-bank", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="A bank built with `memora build DIR --episodic` (needed by memora_episodic).")
@click.option("--kinds", default="eam_qa,replay,generalize", show_default=True, help="Task kinds to run.")
@click.option("--backend", type=ANSWER_POLICY, default="offline", show_default=True,
              help="Answer policy: offline (the deterministic reader, not an LLM), or a model backend (openai, vllm).")
@click.option("--base-url", default=None, help="openai backend: server URL, e.g. http://127.0.0.1:8000/v1.")
@click.option("--model", default=None, help="Model name (openai / vllm backends).")
@click.option("--api-key", default=None, help="openai backend: API key (default: $OPENAI_API_KEY).")
@click.option("--temperature", type=float, default=None, help="Sampling temperature (model backends; default 0.6).")
@click.option("--timeout-s", type=float, default=None, help="openai backend: request timeout in seconds.")
@backend_option_pairs
@click.option("--limit", type=int, default=None, help="At most N items per participant and task kind (smoke runs).")
@click.option("--workers", type=int, default=None,
              help="Processes to run conditions in (default: 2 under offline on a 2+ core machine, 1 for model "
                   "backends). Results do not depend on it.")
@click.option("--concurrency", type=int, default=None,
              help="Agent loops in flight against the model server (model backends; default 32). Records are the "
                   "same as with --concurrency 1, in the same order (timings aside).")
@quiet_option
@executor_options
def run_cmd(bank, out, conditions, participants, tasks, raw_bank, episodic_bank, kinds, backend, base_url, model, api_key,
            temperature, timeout_s, options, limit, workers, concurrency, quiet, executor, ray_address, retries,
            ray_shared):
    """Run the seven-condition evaluation: every condition on every task, one record per item.

    \b
    Examples:
      memora build banks/cal --participants P01,P02,P03,P04
      memora build banks/cal-raw --mode raw --participants P01,P02,P03,P04
      memora build banks/cal-episodic --episodic --participants P01,P02,P03,P04
      memora bench run banks/cal --raw-bank banks/cal-raw --episodic-bank banks/cal-episodic --out runs/offline
      memora bench run banks/cal --raw-bank banks/cal-raw --out runs/qwen --backend openai \\
          --base-url http://127.0.0.1:8000/v1 --model Qwen/Qwen3.6-35B-A3B --concurrency 64
      memora bench run banks/cal --out runs/smoke --conditions no_memory,flat_1d_edited --limit 5
      memora bench run banks/cal --out runs/ray --executor ray   # one Ray task per (condition, participant)
    """
    from memora_graph.bench.run import run_bench

    ex = executor_from(executor, ray_address, retries, ray_shared, base_url)
    if ex.remote and workers:
        raise click.UsageError("--workers sizes the local executor's process pool; under --executor ray every "
                               "(condition, participant) shard is a task")
    base_url = ex.base_urls[0] if ex.base_urls else None  # a list is spread over the Ray tasks
    opts = backend_options(options, base_url=base_url, model=model, api_key=api_key, temperature=temperature,
                           timeout_s=timeout_s)
    progress = progress_bar(quiet, transient=True)
    state: dict = {}

    def on_plan(n):
        state["task"] = progress.add_task("items", total=n)

    def on_item(rec):
        progress.update(state["task"], advance=1, description=f"{rec['condition']} {rec['item_id']}")

    try:
        with progress:
            summary = run_bench(bank, out, conditions=conditions, participants=participants,
                                tasks=tasks, raw_bank=raw_bank, episodic_bank=episodic_bank, backend=backend, backend_options=opts,
                                kinds=tuple(k.strip() for k in kinds.split(",") if k.strip()), limit=limit,
                                on_item=on_item, on_plan=on_plan, workers=workers, concurrency=concurrency,
                                executor=ex)
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    click.echo(f"{summary.done} items run ({summary.failed} failed), {summary.skipped} already done; "
               f"{summary.seconds:.1f} s. Records in {out}/records; `memora bench report {out}` for the tables.")


@bench_group.command("report")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--print/--no-print", "show", default=True, show_default=True, help="Print the markdown report.")
def report_cmd(run_dir, show):
    """Write report.md, report.html and report.json (and results.parquet) for a run directory.

    \b
    Example:
      memora bench report runs/offline
    """
    from memora_graph.bench.report import write_report

    try:
        paths = write_report(run_dir)
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    if show:
        click.echo(paths["markdown"].read_text())
    click.echo("Wrote " + ", ".join(str(p) for p in paths.values()))


@bench_group.command("calibrate")
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@participants_option(default="P01,P02,P03", help="Whose records to fit on (keep the held-out participants out).")
@click.option("--conditions", default="memora_full,memora_episodic", show_default=True,
              help="The conditions whose records are fitted on (comma-separated).")
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Where to write the calibration (default: the package's memora_graph/agent/calibration.json).")
@output_options
def calibrate_cmd(run_dir, participants, conditions, out, fmt):
    """Refit the offline reader's confidence from a run's EAM-QA records: a multinomial logistic
    model over the evidence features each record carries (best option right / E right / another
    option right) and the threshold on P(best) that decides E, chosen for accuracy on the same
    records. Fit on the calibration cohort's P01-P03; check on P04 with `memora bench report`
    after a new run.

    \b
    Example:
      memora bench run banks/cal --episodic-bank banks/cal-epi --conditions memora_full,memora_episodic \\
          --participants P01,P02,P03 --kinds eam_qa --out runs/fit -o calibration none
      memora bench calibrate runs/fit --participants P01,P02,P03
    """
    import polars as pl

    from memora_graph.bench.calibration import fit, save
    from memora_graph.bench.run import load_run

    names = [c.strip() for c in conditions.split(",") if c.strip()]
    records = [r for c, rs in load_run(run_dir)["eam_qa"].items() if c in names for r in rs
               if participants is None or r["participant"] in participants]
    try:
        cal = fit(records, fitted_on={"run": str(run_dir), "participants": participants or "all", "conditions": names})
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    path = save(cal, out)
    rows = [{"feature": f, "w_best": round(cal.coef["best"][i], 3), "w_E": round(cal.coef["E"][i], 3)}
            for i, f in enumerate(cal.features)]
    click.echo(render(pl.DataFrame(rows), fmt))
    if fmt == "table":
        click.echo(f"fitted on {cal.fitted_on['n']} records; E below P(best) = {cal.threshold:.2f}; wrote {path}")


@bench_group.command("compare")
@click.argument("run_a", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("run_b", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--show", type=click.IntRange(min=0), default=10, show_default=True,
              help="List this many differing items (kind, condition, item id, fields that differ).")
@click.option("--check", is_flag=True, help="Exit with status 1 when any record differs or is missing from one run.")
@output_options
def compare_cmd(run_a, run_b, show, check, fmt):
    """Compare two runs record by record, timings set aside: per task kind and condition, the
    records that differ, the answers or plans that changed, the fields that differ, and EAM-QA
    accuracy of each run.

    Use it to show that a change left the evaluation alone (a refactor, another executor, more
    concurrency), or to count what a reader change did.

    \b
    Examples:
      memora bench compare runs/before runs/after
      memora bench compare runs/local runs/ray --check     # exit 1 if anything differs
      memora bench compare runs/before runs/after --json --show 0
    """
    import polars as pl

    from memora_graph.bench.compare import compare_runs

    try:
        result = compare_runs(run_a, run_b)
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    click.echo(render(pl.DataFrame(result.rows), fmt))
    if fmt == "table":
        for d in result.differences[:show]:
            click.echo(f"differs: {d.kind} {d.condition} {d.item_id}: {', '.join(d.fields)}")
        if len(result.differences) > show:
            click.echo(f"... and {len(result.differences) - show} more (--show N)")
        total = sum(r["records_a"] for r in result.rows)
        click.echo("identical (timings aside)" if result.identical else
                   f"{len(result.differences)} of {total} records differ (timings aside)")
    if check and not result.identical:
        raise SystemExit(1)


@bench_group.command("synth")
@click.option("--participant", required=True, help="Whose videos to replay (P01).")
@click.option("--hours", required=True, type=click.FloatRange(min=0, min_open=True), help="Hours of video to make.")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder to write annotations.csv, video_info.csv, the class tables and synth.json into.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed for the renamed objects and reordered actions.")
@click.option("--rename-share", default=0.1, show_default=True, type=click.FloatRange(0, 1),
              help="Share of the object nouns renamed in each replay after the first.")
@click.option("--reorder-share", default=0.1, show_default=True, type=click.FloatRange(0, 1),
              help="Share of actions swapped with the next one in each replay after the first.")
@click.option("--annotations", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="EPIC-style annotation CSV to replay (default: the bundled extension subset).")
def synth_cmd(participant, hours, out, seed, rename_share, reorder_share, annotations) -> None:
    """Make a long-horizon participant: replay a person's videos for --hours, with new video ids
    and shifted times, renaming a share of objects and reordering a share of actions in every
    replay after the first, so memory keeps growing. The same arguments give the same file.

    \b
    Examples:
      memora bench synth --participant P01 --hours 1000 --out runs/synth-1000h
      memora build banks/p01-1000h --annotations runs/synth-1000h/annotations.csv --participants P01
    """
    from memora_graph.bench.synth import synthesize

    r = synthesize(participant.strip().upper(), hours, out, seed=seed, rename_share=rename_share,
                   reorder_share=reorder_share, annotations=annotations)
    click.echo(f"Wrote {r.annotations}: {r.hours:g} h of {r.participant} as {r.replays} replays of its "
               f"{r.source_hours:g} h in {r.videos} videos, {r.actions} actions ({r.renamed} with a renamed object, "
               f"{len(r.new_objects)} new object names; {r.reordered} moved by reordering); seed {r.seed}")
    click.echo(f"build it: memora build BANK --annotations {r.annotations} --participants {r.participant}")


@bench_group.command("noise")
@click.argument("out", type=click.Path(file_okay=False, path_type=Path))
@participants_option(default="P01,P02,P03,P04")
@click.option("--rates", default="0,0.1,0.2,0.3,0.5", show_default=True,
              help="Error rates, comma-separated (0 is the one clean cell every error type shares).")
@click.option("--errors", default="mixed,drop,swap,alias", show_default=True,
              help="Error types, comma-separated: mixed (every type at once), drop, swap, verb, alias, state, time, "
                   "segment.")
@click.option("--conditions", type=CONDITIONS, default="all", show_default=True, help="Conditions to run in each cell.")
@click.option("--kinds", default="eam_qa,replay,generalize", show_default=True, help="Task kinds to run.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of every injected error.")
@click.option("--delta", default=5.0, show_default=True, type=click.FloatRange(min=0),
              help="Largest time shift of the 'time' error, in seconds.")
@click.option("--limit", type=int, default=None, help="At most N items per participant and task kind (smoke runs).")
@click.option("--workers", type=int, default=None, help="Processes per cell's run (as `bench run --workers`; with --jobs 1 only) [default: the cell's "
                   "process runs bench run's condition groups in turn].")
@click.option("--jobs", type=int, default=None,
              help="Cells side by side in long-lived worker processes, each building and reading whole cells "
                   "in-process [default: one per core]. Records do not depend on it.")
@click.option("--annotations", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="EPIC-style annotation CSV to perturb (default: the bundled annotations).")
@click.option("--tasks", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="MEMORA-Bench release folder (default: the bundled calibration cohort P01-P04).")
@click.option("--repairs/--no-repairs", default=False, show_default=True,
              help="Build with the editor's repair rules (form/repair.py: alias, implied state; MEMORA_REPAIRS=on): "
                   "the curve after them.")
@quiet_option
def noise_cmd(out, participants, rates, errors, conditions, kinds, seed, delta, limit, workers, jobs, annotations, tasks,
              repairs, quiet):
    """Noise curves: every condition under perception errors injected at known rates.

    For each error type and rate, writes the noisy annotations with their error log, builds the
    MEMORA, raw and MEMORA-Episodic banks from them, runs the evaluation (`bench run`, resumable),
    and writes OUT/report.md with accuracy and RGP against rate, the break-even rate per error
    type, processed minus raw, and the editor's repair table. Re-running resumes.

    \b
    Examples:
      memora bench noise runs/noise --participants P01,P02,P03,P04 --rates 0,0.1,0.2,0.3,0.5 \\
          --errors mixed,drop,swap,alias
      memora bench noise runs/noise-p01 --participants P01 --rates 0,0.2 --errors mixed
      memora bench compare runs/noise/cells/clean-0/run runs/noise/cells/mixed-0.2/run
    """
    from memora_graph.bench.noise import parse_errors, parse_rates, run_noise

    try:
        if not participants:
            raise click.BadParameter("name the participants", param_hint="'--participants'")
        sweep = run_noise(out, participants, parse_rates(rates), parse_errors(errors), conditions=conditions,
                          seed=seed, delta=delta, kinds=tuple(k.strip() for k in kinds.split(",") if k.strip()),
                          limit=limit, workers=workers, jobs=jobs, annotations=annotations, repairs=repairs,
                          tasks=tasks, on_step=None if quiet else (lambda s: click.echo(s, err=True)))
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    click.echo(f"{len(sweep.cells)} cells in {sweep.seconds:.1f} s wall, {sweep.cpu_seconds:.0f} CPU-s, {sweep.jobs} "
               f"job(s); report in {out}/report.md")


@bench_group.command("perceiver-errors")
@click.argument("reference", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.argument("perceived", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--participant", default=None,
              help="Whose videos a narration table without a participant column describes.")
@output_options
def perceiver_errors_cmd(reference, perceived, participant, fmt):
    """A perceiver's error rate per type against annotations of the same videos: the rates
    `memora bench noise` sweeps, so the noise curves give its operating point (docs/robustness.md).

    REFERENCE is an EPIC-style annotation CSV (the human annotations); PERCEIVED is another, or a
    free-text narration table (CSV, JSONL or Parquet: video_id, start, end, text), read the way
    `memora build --narrations` reads it. Actions are matched by narration_id, else by time overlap.

    \b
    Examples:
      memora bench perceiver-errors annotations.csv my-vlm-narrations.csv --participant P01
      memora bench perceiver-errors bench/data/epic-kitchens-100/extension_narrations.csv \\
          runs/noise/cells/mixed-0.2/annotations/annotations.csv
    """
    import polars as pl

    from memora_graph.perceive.annotations import REQUIRED_COLUMNS, load_annotations, load_class_tables
    from memora_graph.perceive.noise import measure_errors

    try:
        head = perceived.read_text(errors="replace").splitlines()[0] if perceived.suffix == ".csv" else ""
        if all(c in head.split(",") for c in REQUIRED_COLUMNS):
            got = load_annotations(perceived)
            classes = load_class_tables(perceived.parent)
        else:
            from memora_graph.perceive.narrations import NarrationReader, load_narrations

            reader = NarrationReader()
            got, _, _ = load_narrations(perceived, participant, reader)
            classes = reader.classes
        ref = load_annotations(reference, participants=sorted(got["participant_id"].unique().to_list()))
        ref = ref.filter(pl.col("video_id").is_in(got["video_id"].unique().to_list()))
        if ref.is_empty():
            raise MemoraError(f"{reference}: no annotated action in the videos of {perceived}")
        rates = measure_errors(ref, got, classes)
    except MemoraError as exc:
        raise click.ClickException(str(exc)) from exc
    rows = [{"error": k, "errors": v["errors"], "units": v["units"], "rate": v["rate"]} for k, v in rates.items()]
    click.echo(render(pl.DataFrame(rows), fmt))
    if fmt == "table":
        click.echo(f"largest time shift: {rates['time']['delta']} s (`memora bench noise --delta`)")

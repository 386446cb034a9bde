"""The `memora` command line: parse, call the library, render. No logic lives here.

Commands of other modules are loaded on demand (`LazyGroup`): `memora --help` imports click and
this module, nothing else; `memora tool ...` imports what a tool needs.

Every command lives in this package, and only this package imports click: the root commands (build,
query, run, stats, ...) here, the others one module a subject (`agent`, `bench`, `consolidate`,
`explore`, `integrity`, `retrieve`, `serve`, `transfer`), the benchmark commands (`memora perf ...`)
in `perf/`, what they share in `options` and `executors`, and the reference page generator in `docs`.
"""

from __future__ import annotations

import shlex
import statistics

import click

from memora_graph.cli.executors import executor_from, executor_options
from memora_graph.cli.options import (
    BACKEND, EDITOR_POLICY, LazyGroup, output_options, participants_option, progress_bar, quiet_option,
)
from memora_graph.output import render


def _params(pairs) -> dict:
    from memora_graph.cypher_guard import parse_params

    return parse_params(pairs)


def _prepare(command: click.Command) -> None:
    """Every loaded command that opens a bank gets `--no-verify` (memora_graph/cli/integrity.py)."""
    from memora_graph.cli.integrity import add_no_verify

    add_no_verify(command)


param_option = click.option(
    "-p", "--param", "params", type=(str, str), multiple=True, metavar="NAME VALUE",
    help="Bind $NAME to VALUE (JSON if it parses, else a string). Repeatable.",
)

# name -> (where the command lives, its one-line help as `memora --help` lists it without importing it;
# tests/cli/test_cli_options.py checks it against the command's own)
COMMANDS = {
    "ask": ("memora_graph.cli.agent:ask_cmd",
            "Ask one person's memory a question, answered by the typed reader (deterministic, no model)."),
    "bench": ("memora_graph.cli.bench:bench_group",
              "MEMORA-Bench: generate EAM-QA and Planning tasks from action annotations, and validate release "
              "folders (the bundled calibration cohort, a full release, or a generated suite)."),
    "consolidate": ("memora_graph.cli.consolidate:consolidate_cmd",
                    "Re-run offline consolidation and enrichment on an existing bank."),
    "explore": ("memora_graph.cli.explore:explore_cmd",
                "Write an explorer page for one participant's memory: one HTML file, nothing fetched when opened."),
    "export": ("memora_graph.cli.transfer:export_cmd",
               "Export one participant's memory: every node and relationship, with its ids and properties."),
    "forget": ("memora_graph.cli.integrity:forget_cmd",
               "Remove every trace of one person from a bank: their database (with its write-ahead log and shadow "
               "files, and so its indexes), staged videos of an unfinished build, rebuild leftovers, their baseline "
               "caches under BANK/.cache/ (and the embedding cache all participants share, which holds vectors of "
               "their texts; it is rebuilt on demand), and their manifest entry."),
    "import": ("memora_graph.cli.transfer:import_cmd",
               "Import a JSON or Parquet export (`memora export`) into BANK as a new participant."),
    "plan": ("memora_graph.cli.agent:plan_cmd",
             "Plan a goal from one person's memory, with the offline planner (deterministic, no model)."),
    "remember": ("memora_graph.cli.form:remember_cmd",
                 "Remember what just happened: perceive a narration, embed it, run the online editor and commit."),
    "serve": ("memora_graph.cli.serve:serve_cmd",
              "Serve a memory bank to agents over the Model Context Protocol (MCP)."),
    "tool": ("memora_graph.cli.retrieve:tool_cmd",
             "Call one retrieval tool on one participant's memory."),
    "tools": ("memora_graph.cli.retrieve:tools_cmd",
              "List the retrieval tools with their arguments, the store each reads, and the memory representation "
              "(family) they belong to: MEMORA's typed stores, or a baseline's."),
    "verify": ("memora_graph.cli.integrity:verify_cmd",
               "Check a bank deeply: per participant, the database's sha256 and size against the record of its last "
               "write, rows per table against the manifest, rows of other participants, write-ahead log or shadow "
               "files, unfinished writes or builds, staged videos; and files that belong to no participant."),
}
PERF_COMMANDS = {
    "build": ("memora_graph.cli.perf.build:perf_build",
              "Build the bundled annotations from scratch and print where the time went: every phase, summing to "
              "the wall time (to worker-seconds with --jobs > 1), and the share of graph work (all but embedding and "
              "model load)."),
    "decode": ("memora_graph.cli.perf.video:perf_decode",
               "Decode and segment a 60 s synthetic video; print the multiple of real time (target >= 20x)."),
    "encoders": ("memora_graph.cli.perf.encoders:perf_encoders_cmd",
                 "Compare the query encoders (MEMORA_QUERY_ENCODER): import, load and export time, latency of a new "
                 "query, recall@10 against PyTorch exact search on BANK; and passage throughput in batches."),
    "live": ("memora_graph.cli.perf.live:perf_live_cmd",
             "Live memory: remember latency, tool latency while remembering, incremental consolidation."),
    "model": ("memora_graph.cli.perf.model:perf_model",
              "The evaluation and a video build against a loopback model server with real latency, at --concurrency 1 and N: wall time, calls, calls in flight, speedup, our overhead per call (targets: >= 25x at 64, <= 5 ms per call)."),
    "ray": ("memora_graph.cli.perf.ray:perf_ray",
            "Ray's overhead against the local executor on a full build, measured side by side."),
    "scale": ("memora_graph.cli.perf.scale:perf_scale_cmd",
              "Build 10, 100 and 1,000 hours of one participant and print, per size: build seconds per hour, bank size, open time, peak resident memory, p50/p95 per tool for the in-process and the K\u00f9zu HNSW recipes, and the size at which HNSW becomes faster."),
    "serve": ("memora_graph.cli.perf.serve:perf_serve_cmd",
              "Warm tool-call latency of `memora serve` over streamable HTTP on loopback."),
    "startup": ("memora_graph.cli.perf.startup:perf_startup_cmd",
                "How fast one-shot commands start: `memora --help` and a one-shot `memora tool` as new processes "
                "(median wall and CPU seconds of several runs)."),
    "tools": ("memora_graph.cli.perf.tools:perf_tools_cmd",
              "Time every tool over a fixed query set: p50 / p95 per call (query embedding included), next to the "
              "exact numpy top-k floor, and recall@10 of every vector search against exact."),
    "verify": ("memora_graph.cli.perf.verify:perf_verify_cmd",
               "What checking a database before opening it costs, against a one-shot command."),
    "video": ("memora_graph.cli.perf.video:perf_video",
              "Build from a synthetic video against a scripted server on 127.0.0.1 and print the graph work per "
              "segment: everything except decoding and waiting for the model (target <= 50 ms)."),
}


@click.group(cls=LazyGroup, lazy=COMMANDS, on_load=_prepare)
@click.version_option(package_name="memora-graph")
def main():
    """memora: build, explore and evaluate embodied action memory graphs.

    \b
    Quick start:
      memora build banks/epic                 # all 18 participants from the bundled annotations
      memora stats banks/epic
      memora run banks/epic object_history -p participant P01 -p object plate -p video P01_109
      memora query banks/epic "MATCH (e:Entity) WHERE e.participant = 'P01' RETURN e.name LIMIT 5"
    """
    from memora_graph.cli.integrity import show_bank_notices

    show_bank_notices()


@main.command()
@click.argument("bank", type=click.Path(file_okay=False))
@participants_option()
@click.option("--annotations", type=click.Path(exists=True, dir_okay=False), help="EPIC-style CSV (default: the bundled subset).")
@click.option("--narrations", type=click.Path(exists=True, dir_okay=False),
              help="Free-text narrations instead: CSV, JSONL or Parquet with video_id, start, end, text and optional "
                   "participant (Ego4D-style '#C C takes a cup' works as given). Words are read into EPIC verb / noun "
                   "classes; those no class covers are kept and reported.")
@click.option("--mode", type=EDITOR_POLICY, default="edited", show_default=True,
              help="'raw' stores one record per observation, unedited (baselines, compression figure).")
@click.option("--backend", type=BACKEND, default="offline", show_default=True,
              help="Memory processors: 'offline' is the deterministic CPU policy (annotations only); 'openai' "
                   "any OpenAI-compatible server (vllm serve, llama.cpp); 'vllm' an in-process engine.")
@click.option("--video", "video", type=click.Path(exists=True), help="Build from a video file, or every video in a directory.")
@click.option("--participant", help="With --video (or --narrations without a participant column): whose memory it "
                                    "goes into (P01).")
@click.option("--video-id", help="With --video FILE: the id to store it under (default: the file name).")
@click.option("--base-url", help="With --backend openai: the server, e.g. http://127.0.0.1:8000/v1.")
@click.option("--perception-model", help="The vision-language model (default: the first the server lists).")
@click.option("--editor-model", help="The entity-editor model (default: the perception model).")
@click.option("--editor-base-url", help="A separate server for the editor model (default: --base-url).")
@click.option("--consolidation", type=click.Choice(["deterministic", "llm"]), default=None,
              help="With --video: the offline consolidation + enrichment processors (default: 'llm', by the "
                   "--consolidation-model on the same server, with a model backend; see `memora consolidate`).")
@click.option("--consolidation-model", help="With --video: the consolidation / enrichment model (default: the editor model).")
@click.option("--audio/--no-audio", default=None,
              help="Send each clip's audio to the perception model (default: only for audio-capable models, e.g. *Omni*).")
@click.option("--embed-model", default=None, help="sentence-transformers model name or path (default: bundled all-MiniLM-L6-v2).")
@click.option("--episodic", is_flag=True,
              help="Skip offline consolidation and enrichment (no routines or preferences): the MEMORA-Episodic condition.")
@click.option("--fts", is_flag=True,
              help="Also build Kùzu's full-text indexes, for the 'fts' / 'kuzu' / 'hnsw' retrieval recipes only "
                   "(the default recipe needs none; `memora index` adds them later).")
@click.option("--jobs", type=click.IntRange(min=1), default=None,
              help="Participants built side by side, one worker process each (default: one per core, at most 4, "
                   "and at least two participants per worker).")
@click.option("--rebuild", "rebuild", metavar="VIDEO", multiple=True,
              help="Rebuild the participant that owns this video (or a participant id) from scratch, e.g. after "
                   "its annotations changed (memory formation is sequential). Repeatable or comma-separated.")
@click.option("--concurrency", type=click.IntRange(min=1), default=None,
              help="With --video: videos perceived at once (each video's clips in order; the editor takes the "
                   "videos one after another) and consolidation calls in flight (default 8; 1: one call at a time).")
@quiet_option
@executor_options
def build(bank, participants, annotations, narrations, mode, backend, video, participant, video_id, base_url, perception_model,
          editor_model, editor_base_url, consolidation, consolidation_model, audio, embed_model, episodic, fts, jobs,
          rebuild, concurrency, quiet, executor, ray_address, retries, ray_shared):
    """Build (or resume) a memory bank from action annotations, or from video with --video.

    Re-running the same command continues where a killed build stopped: finished videos
    are kept and nothing is written twice.

    \b
    Examples:
      memora build banks/epic
      memora build banks/p01 --participants P01,P02
      memora build banks/raw --mode raw --participants P01
      memora build banks/episodic --episodic          # MEMORA-Episodic: no routines / preferences
      memora build banks/epic --fts                   # also the full-text indexes (recipes fts, kuzu)
      memora build banks/epic --rebuild P01_102       # rebuild P01 (e.g. its annotations changed)
      memora build banks/ego --narrations narrations.csv --participant P01   # video_id,start,end,text
      memora build banks/home --video kitchen.mp4 --participant P01 --backend openai \\
          --base-url http://127.0.0.1:8000/v1 --perception-model Qwen/Qwen2.5-VL-7B-Instruct \\
          --editor-model Qwen/Qwen3-30B-A3B-Instruct-2507   # the same server consolidates with it
      memora build banks/epic --executor ray --ray-address auto   # one Ray task per participant (docs/scaling.md)
    """
    video_opts = dict(participant=participant, video_id=video_id, base_url=base_url, perception_model=perception_model,
                      editor_model=editor_model, editor_base_url=editor_base_url, audio=audio,
                      consolidation=consolidation, consolidation_model=consolidation_model)
    rebuild = [r.strip() for x in rebuild for r in x.split(",") if r.strip()]
    ex = executor_from(executor, ray_address, retries, ray_shared, base_url)
    if ex.remote and jobs:
        raise click.UsageError("--jobs sizes the local executor's process pool; under --executor ray every "
                               "participant is a task and the cluster's CPUs set how many run at once")
    if video:
        if rebuild:
            raise click.UsageError("--rebuild applies to annotation builds; to rebuild a participant from video, "
                                   "`memora forget BANK --participant P` and build it again with all its videos")
        if annotations or narrations or mode != "edited" or participants is not None or jobs:
            raise click.UsageError("--video builds one --participant, edited; drop --annotations, --narrations, --mode, "
                                   "--participants and --jobs")
        if ex.remote:  # one task per participant: --participant, or a directory of P01/, P02/ ... folders
            return _build_video_ray(bank, video, backend, embed_model, quiet, ex,
                                   {**video_opts, "episodic": episodic, "fts": fts})
        if not participant:
            raise click.UsageError("--video needs --participant (whose memory this is, e.g. P01)")
        return _build_video(bank, video, backend, embed_model, quiet, {**video_opts, "episodic": episodic, "fts": fts,
                                                                        "concurrency": concurrency or 8})
    if concurrency is not None:
        raise click.UsageError("--concurrency applies to --video builds (annotation builds use --jobs)")
    if narrations and annotations:
        raise click.UsageError("give --annotations (EPIC's columns) or --narrations (free text), not both")
    if narrations and rebuild:
        raise click.UsageError("--rebuild applies to annotation builds")
    narration_participant = video_opts.pop("participant") if narrations else None
    given = [f"--{k.replace('_', '-')}" for k, v in video_opts.items() if v is not None]
    if given:
        raise click.UsageError(f"{', '.join(given)} only apply with --video")
    if backend != "offline":
        raise click.UsageError(f"--backend {backend} applies to --video builds; annotation builds use the offline processors")

    progress = progress_bar(quiet)
    task = {}

    def on_plan(plan):
        task["id"] = progress.add_task("building", total=sum(len(v) for v in plan.values()))

    def on_video(p, video, n):
        progress.update(task["id"], advance=1, description=f"{p} {video}")

    try:  # a Ctrl-C at any moment: one line, and the bank as a killed build leaves it (resumable)
        from memora_graph.pipeline import build_bank
        from memora_graph.retrieve.view import persist_bank

        with progress:
            result = build_bank(bank, participants, annotations, mode=mode, embed_model=embed_model, on_plan=on_plan,
                                on_video=on_video, episodic=episodic, fts=fts, jobs=jobs, rebuild=rebuild or None,
                                isolate=True, on_notice=lambda text: click.echo(text, err=True), executor=ex,
                                narrations=narrations, participant=narration_participant)
        stores = persist_bank(bank, [r.participant for r in result.participants])
    except KeyboardInterrupt:
        again = " ".join(["memora build", shlex.quote(str(bank)), *(["--participants", ",".join(participants)]
                                                                   if participants else []),
                          *(["--narrations", shlex.quote(str(narrations))] if narrations else []),
                          *(["--participant", narration_participant] if narration_participant else [])])
        click.echo(f"memora build: interrupted; what was built is kept, and `{again}` resumes it", err=True)
        raise click.exceptions.Exit(130) from None
    from memora_graph.stats import build_summary
    from memora_graph.text import counted

    frame, lines = build_summary(result, bank, episodic=episodic, mode=mode, fts=fts)
    click.echo(render(frame))
    for line in lines:
        click.echo(line)
    if result.unknown is not None:
        click.echo(f"narrations: {result.unknown.summary()}")
    click.echo(f"tool stores (what one-shot tools map instead of querying Kùzu): {counted(len(stores.written), 'participant')} "
               f"in {stores.seconds:.1f} s")


def _build_video(bank, video, backend, embed_model, quiet, opts):
    from memora_graph.pipeline import build_from_video
    from memora_graph.stats import video_build_summary

    progress = progress_bar(quiet)
    tasks = {}

    def on_video(video_id, n_clips):
        tasks[video_id] = progress.add_task(f"{opts['participant']} {video_id}", total=n_clips)

    def on_segment(video_id, turn, error):
        progress.update(tasks[video_id], advance=1)

    with progress:
        res = build_from_video(bank, video, backend=backend, embed_model=embed_model, on_video=on_video,
                               on_segment=on_segment, **opts)
    frame, lines, warnings = video_build_summary(res, bank)
    click.echo(render(frame))
    for line in lines:
        click.echo(line)
    for line in warnings:
        click.echo(line, err=True)


def _video_jobs(video: str, participant: str | None) -> list[tuple[str, str]]:
    """(participant, path) per Ray task: the one --participant, or each P01/, P02/ ... folder of a
    directory (that participant's videos, built in order)."""
    from pathlib import Path

    from memora_graph.bank import is_participant_id

    path = Path(video).resolve()
    if participant:
        return [(participant, str(path))]
    folders = sorted(d for d in path.iterdir() if d.is_dir() and is_participant_id(d.name)) if path.is_dir() else []
    if not folders:
        raise click.UsageError(f"{video}: give --participant, or a directory with one folder per participant "
                               "(P01/, P02/ ...) to build each as a Ray task")
    return [(d.name, str(d)) for d in folders]


def _build_video_ray(bank: str, video: str, backend: str, embed_model: str | None, quiet: bool, ex,
                     opts: dict) -> None:
    """`memora build --video ... --executor ray`: one task per participant, one progress bar."""
    import polars as pl

    from memora_graph.bank import Bank, check_writable
    from memora_graph.pipeline.ray import video_on_ray
    from memora_graph.stats import decision_shares

    jobs = _video_jobs(video, opts.pop("participant"))
    if opts.get("video_id") and len(jobs) > 1:
        raise click.UsageError("--video-id names one video of one participant")
    kwargs = {**opts, "backend": backend, "embed_model": embed_model}
    progress = progress_bar(quiet)
    task = progress.add_task("video clips", total=0)

    def on_event(ev: tuple) -> None:
        kind, p, v, value = ev
        if kind == "video":
            progress.update(task, total=(progress.tasks[0].total or 0) + value, description=f"{p} {v}")
        else:
            progress.update(task, advance=1)

    with progress:
        results = video_on_ray(ex, Bank(check_writable(bank)), jobs, kwargs, on_event=on_event,
                               on_notice=lambda text: click.echo(text, err=True))
    rows = []
    for res in results:
        c, shares = res.counts, decision_shares(res.decisions)
        rows.append({"participant": res.participant, "videos": len(res.videos),
                     "built": sum(not v.get("skipped") for v in res.videos), "segments": c.get("segments"),
                     "entities": c.get("entities"), "state_events": c.get("state_events"), "places": c.get("places"),
                     "NOOP%": shares["NOOP"], "UPDATE%": shares["UPDATE"], "ADD%": shares["ADD"],
                     "DELETE%": shares["DELETE"], "model_calls": len(res.calls),
                     "failed_calls": sum(not r.ok for r in res.calls), "seconds": round(res.wall_seconds, 1)})
    click.echo(render(pl.DataFrame(rows)))
    click.echo(f"bank {bank}: {len(rows)} participant(s) built from video as Ray tasks")


@main.command()
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--fts", is_flag=True, help="Full-text indexes: the 'fts' and 'kuzu' retrieval recipes (and 'hnsw').")
@click.option("--hnsw", is_flag=True, help="HNSW vector indexes on segments and entities: the 'hnsw' recipe.")
@participants_option()
@output_options
def index(bank, fts, hnsw, participants, fmt):
    """Add Kùzu's optional indexes to a built bank (a build makes none unless `--fts`).

    The default retrieval recipe ('inprocess') needs no index; 'fts' and 'kuzu' read the
    full-text indexes, 'hnsw' both kinds. An index a database has is kept (never dropped and
    re-created); rows added by a later build join it. The manifest records which exist.

    \b
    Examples:
      memora index banks/epic --fts
      memora index banks/epic --fts --hnsw --participants P01
    """
    import polars as pl

    from memora_graph.bank import Bank

    if not (fts or hnsw):
        raise click.UsageError("say which indexes to build: --fts and/or --hnsw")
    from memora_graph.retrieve.view import persist_bank
    from memora_graph.text import counted

    done = Bank(bank).build_indexes(participants, fts=fts, hnsw=hnsw)
    rows = [{"participant": p, "created": ", ".join(r["created"]) or "(had them)", "indexes": ", ".join(r["indexes"]),
             "seconds": round(r["seconds"], 1)} for p, r in done.items()]
    click.echo(render(pl.DataFrame(rows), fmt))
    stores = persist_bank(bank, list(done))  # an index is a write: the tool stores are stale until written again
    click.echo(f"tool stores written again: {counted(len(stores.written), 'participant')} in {stores.seconds:.1f} s", err=True)


@main.command()
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.argument("cypher")
@param_option
@click.option("--participant", help="Only this participant's database (default: every participant, concatenated).")
@click.option("--write", is_flag=True, help="Allow data writes (CREATE, MERGE, SET, DELETE, REMOVE) to the one "
                                            "--participant; never files, extensions or the schema.")
@click.option("--timeout", type=float, default=30.0, show_default=True, metavar="SECONDS",
              help="Stop the query after this long.")
@click.option("--max-rows", type=click.IntRange(min=1), default=10_000, show_default=True,
              help="Show at most this many rows (a notice says when the result was cut); --csv writes every row.")
@output_options
def query(bank, cypher, params, participant, write, timeout, max_rows, fmt):
    """Run one ad-hoc Cypher statement over a bank (read-only unless --write).

    The statement must be one read query (MATCH, OPTIONAL MATCH, UNWIND, WITH, RETURN, or CALL of
    a read-only procedure such as show_tables); COPY, LOAD, EXPORT, ATTACH, extensions, schema
    and transaction statements are refused before anything runs. $participant is bound to the
    participant whose database is read unless -p participant says otherwise. The query runs in a
    process the kernel confines (Landlock) to the participants' database files: no other file, no
    network; a warning says so where the kernel cannot. At most --max-rows rows are shown; --csv
    streams every row.

    \b
    Examples:
      memora query banks/epic "MATCH (p:Place) WHERE p.participant = \\$participant RETURN p.name, p.turn_count" -p participant P01
      memora query banks/epic "MATCH (e:Entity) RETURN e.participant, count(*) AS n" --csv
      memora query banks/epic "CALL show_tables() RETURN name, type" --participant P01
      memora query banks/epic "MATCH (e:Entity {object_id: 'plate'}) SET e.state = 'clean'" --participant P01 --write
    """
    import sys

    from memora_graph.adhoc import run_query
    from memora_graph.confine import mode

    confinement = mode()
    if not confinement.confined:
        click.echo(f"warning: {confinement.describe()}", err=True)
    csv_fd = None
    if fmt == "csv":  # every row, streamed by the query process to standard output
        try:
            sys.stdout.flush()
            csv_fd = sys.stdout.fileno()
        except (AttributeError, OSError, ValueError):  # not a real file (a test runner's buffer): capped rows
            csv_fd = None
    result = run_query(bank, cypher, _params(params), participant=participant, write=write, timeout=timeout,
                       max_rows=max_rows, csv_fd=csv_fd)
    if not result.streamed:
        click.echo(render(result.frame, fmt))
    if result.notice:
        click.echo(f"notice: {result.notice}", err=True)


@main.command("queries")
@output_options
def list_queries(fmt):
    """List the named queries with their parameters and descriptions.

    \b
    Example:
      memora queries
    """
    import polars as pl

    from memora_graph.queries import load_queries

    rows = [{"name": q.name, "params": ", ".join(q.params), "description": q.description}
            for q in load_queries().values() if not q.name.startswith("_")]
    click.echo(render(pl.DataFrame(rows), fmt))


@main.command()
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.argument("name")
@param_option
@output_options
def run(bank, name, params, fmt):
    """Run a named query (see `memora queries`).

    Without `-p participant`, a participant-scoped query runs over every participant.

    \b
    Examples:
      memora run banks/epic object_history -p participant P01 -p object plate -p video P01_109
      memora run banks/epic places_most_used --json
    """
    from memora_graph.bank import Bank
    from memora_graph.cypher_guard import check_participant
    from memora_graph.queries import get_query

    q = get_query(name)
    bound = _params(params)
    b = Bank(bank)
    if "participant" in bound:
        check_participant(bound["participant"], "-p participant")
    if "participant" in q.params and "participant" not in bound:
        df = b.run_each(name, **bound)
    else:
        pid = bound.get("participant") or b.participants()[0]
        with b.open(pid) as store:
            df = store.run(q, **bound)
    click.echo(render(df, fmt))


@main.command()
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--participant", help="One participant (default: all).")
@click.option("--calls", type=click.Choice(["role", "segment", "failed"]), is_flag=False, flag_value="role",
              default=None, help="Model calls (video builds, memora consolidate) instead: cost and latency per role (the default), "
                                 "per segment, or the failed calls.")
@output_options
def stats(bank, participant, calls, fmt):
    """Counts per store, entity compression and the editor's decision mix.

    Compression = entity observations without editing (state events) / entity records after
    editing, as in the paper's "Active memory formation in Entity Memory".

    \b
    Examples:
      memora stats banks/epic
      memora stats banks/epic --participant P01 --json
      memora stats banks/home --calls              # model cost and latency per role
      memora stats banks/home --calls segment      # ... per 10 s segment
    """
    from memora_graph.stats import bank_stats, call_stats

    one = None if participant is None else [participant]  # --participant "" is an error, not everyone
    if calls:
        df = call_stats(bank, one, by=calls)
        click.echo(render(df, fmt) if not df.is_empty() or fmt != "table" else "no model calls recorded in this bank")
        return
    df = bank_stats(bank, one)
    click.echo(render(df, fmt))
    if fmt == "table" and df.height > 1:
        ratios = [r for r in df["compression"].to_list() if r]
        click.echo(f"compression: median {statistics.median(ratios):.1f}x, min {min(ratios):.1f}x, max {max(ratios):.1f}x")


# named perf_group, not perf: the package memora_graph/cli/perf/ (where the benchmark commands live) takes
# the attribute `perf` of this module once one of them is imported
@main.group("perf", cls=LazyGroup, lazy=PERF_COMMANDS, on_load=_prepare)
def perf_group():
    """Benchmarks that print their figures (not timed tests)."""


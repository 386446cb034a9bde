"""The `memora` command line: parse, call the library, render. No logic lives here."""

from __future__ import annotations

import statistics
import sys

import click
import polars as pl

from memora_graph.errors import MemoraError
from memora_graph.executors.cli import executor_from, executor_options
from memora_graph.output import output_options, render


class _Group(click.Group):
    """Turns every MemoraError into `Error: ...` and exit code 1, never a traceback."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except MemoraError as exc:
            raise click.ClickException(str(exc)) from exc


def _params(pairs) -> dict:
    from memora_graph.cypher_guard import parse_params

    return parse_params(pairs)


param_option = click.option(
    "-p", "--param", "params", type=(str, str), multiple=True, metavar="NAME VALUE",
    help="Bind $NAME to VALUE (JSON if it parses, else a string). Repeatable.",
)


@click.group(cls=_Group)
@click.version_option(package_name="memora-graph")
def main():
    """memora: build, explore and evaluate embodied action memory graphs.

    \b
    Quick start:
      memora build banks/epic                 # all 18 participants from the bundled annotations
      memora stats banks/epic
      memora run banks/epic object_history -p participant P01 -p object plate
      memora query banks/epic "MATCH (e:Entity) WHERE e.participant = 'P01' RETURN e.name LIMIT 5"
    """


@main.command()
@click.argument("bank", type=click.Path(file_okay=False))
@click.option("--participants", default="all", show_default=True, help="Comma-separated ids (P01,P02) or 'all'.")
@click.option("--annotations", type=click.Path(exists=True, dir_okay=False), help="EPIC-style CSV (default: the bundled subset).")
@click.option("--mode", type=click.Choice(["edited", "raw"]), default="edited", show_default=True,
              help="'raw' stores one record per observation, unedited (baselines, compression figure).")
@click.option("--backend", type=click.Choice(["offline", "openai", "vllm"]), default="offline", show_default=True,
              help="Memory processors: 'offline' is the deterministic CPU policy (annotations only); 'openai' "
                   "any OpenAI-compatible server (vllm serve, llama.cpp); 'vllm' an in-process engine.")
@click.option("--video", "video", type=click.Path(exists=True), help="Build from a video file, or every video in a directory.")
@click.option("--participant", help="With --video: whose memory the video goes into (P01).")
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
@click.option("--quiet", is_flag=True, help="No progress bar.")
@executor_options
def build(bank, participants, annotations, mode, backend, video, participant, video_id, base_url, perception_model,
          editor_model, editor_base_url, consolidation, consolidation_model, audio, embed_model, episodic, fts, jobs,
          rebuild, quiet, executor, ray_address, retries, ray_shared):
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
      memora build banks/home --video kitchen.mp4 --participant P01 --backend openai \\
          --base-url http://127.0.0.1:8000/v1 --perception-model Qwen/Qwen2.5-VL-7B-Instruct \\
          --editor-model Qwen/Qwen3-30B-A3B-Instruct-2507   # the same server consolidates with it
      memora build banks/epic --executor ray --ray-address auto   # one Ray task per participant (README "Ray")
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

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
        if annotations or mode != "edited" or participants != "all" or jobs:
            raise click.UsageError("--video builds one --participant, edited; drop --annotations, --mode, --participants "
                                   "and --jobs")
        if ex.remote:  # one task per participant: --participant, or a directory of P01/, P02/ ... folders
            from memora_graph.executors.cli import build_video_ray

            return build_video_ray(bank, video, backend, embed_model, quiet, ex,
                                   {**video_opts, "episodic": episodic, "fts": fts})
        if not participant:
            raise click.UsageError("--video needs --participant (whose memory this is, e.g. P01)")
        return _build_video(bank, video, backend, embed_model, quiet, {**video_opts, "episodic": episodic, "fts": fts})
    given = [f"--{k.replace('_', '-')}" for k, v in video_opts.items() if v is not None]
    if given:
        raise click.UsageError(f"{', '.join(given)} only apply with --video")
    if backend != "offline":
        raise click.UsageError(f"--backend {backend} applies to --video builds; annotation builds use the offline processors")

    from memora_graph.bank import parse_participants
    from memora_graph.stats import decision_shares
    from memora_graph.pipeline import build_bank

    pids = parse_participants(participants)
    progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                        disable=quiet, transient=False)
    task = {}

    def on_plan(plan):
        task["id"] = progress.add_task("building", total=sum(len(v) for v in plan.values()))

    def on_video(p, video, n):
        progress.update(task["id"], advance=1, description=f"{p} {video}")

    with progress:
        result = build_bank(bank, pids, annotations, mode=mode, embed_model=embed_model, on_plan=on_plan, on_video=on_video,
                            episodic=episodic, fts=fts, jobs=jobs, rebuild=rebuild or None, isolate=True,
                            on_notice=lambda text: click.echo(text, err=True), executor=ex)
    rows = []
    for r in result.participants:
        shares = decision_shares(r.decisions)
        rows.append({
            "participant": r.participant, "videos": r.counts.get("videos"), "built": r.videos_built,
            "segments": r.counts.get("segments"), "entities": r.counts.get("entities"),
            "state_events": r.counts.get("state_events"), "places": r.counts.get("places"),
            "NOOP%": shares["NOOP"], "UPDATE%": shares["UPDATE"], "ADD%": shares["ADD"], "DELETE%": shares["DELETE"],
            "compression": round(r.compression, 1), "routines": result.inferred.get(r.participant, {}).get("routines"),
            "preferences": result.inferred.get(r.participant, {}).get("preferences"), "seconds": round(r.timings.total, 1),
        })
    click.echo(render(pl.DataFrame(rows)))
    across = f" (seconds summed over {result.jobs} worker processes)" if result.jobs > 1 else ""
    click.echo(f"bank {bank}: {len(rows)} participants, {result.segments} new segments in {result.wall_seconds:.1f} s: "
               f"embedding {result.embedding_seconds:.1f} s, model load {result.model_seconds:.1f} s, graph work "
               f"{result.graph_seconds:.1f} s{across}; `memora perf build` splits it")
    click.echo("inferred knowledge: none (MEMORA-Episodic)" if episodic or mode == "raw" else
               f"inferred knowledge (consolidation + enrichment): {result.finish.get('consolidation', 0.0):.1f} s")
    if fts:
        click.echo(f"full-text indexes: {result.finish.get('indexes', 0.0):.1f} s")


def _build_video(bank, video, backend, embed_model, quiet, opts):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from memora_graph.stats import decision_shares
    from memora_graph.pipeline import build_from_video

    progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                        disable=quiet, transient=False)
    tasks = {}

    def on_video(video_id, n_clips):
        tasks[video_id] = progress.add_task(f"{opts['participant']} {video_id}", total=n_clips)

    def on_segment(video_id, turn, error):
        progress.update(tasks[video_id], advance=1)

    with progress:
        res = build_from_video(bank, video, backend=backend, embed_model=embed_model, on_video=on_video,
                               on_segment=on_segment, **opts)
    rows = [{"video": v["video"], "turns": v.get("turns", 0), "segments": v.get("segments", 0),
             "failed_turns": len(v.get("perception_failed", [])) + len(v.get("editor_failed", [])),
             "seconds": v.get("seconds", 0.0), "status": "already built" if v.get("skipped") else "built"}
            for v in res.videos]
    click.echo(render(pl.DataFrame(rows)))
    c, shares = res.counts, decision_shares(res.decisions)
    tokens = sum((r.tokens_in or 0) + (r.tokens_out or 0) for r in res.calls)
    click.echo(f"bank {bank}, {res.participant}: {c.get('segments')} segments, {c.get('entities')} entities, "
               f"{c.get('state_events')} state events, {c.get('places')} places; editor NOOP {shares['NOOP']}% "
               f"UPDATE {shares['UPDATE']}% ADD {shares['ADD']}% DELETE {shares['DELETE']}%")
    click.echo(f"{len(res.calls)} model calls ({sum(not r.ok for r in res.calls)} failed, {tokens} tokens) in "
               f"{res.wall_seconds:.1f} s: waiting for the model {res.model_seconds:.1f} s, decoding "
               f"{res.decode_seconds:.1f} s, graph work {res.graph_seconds:.1f} s, consolidation {res.inferred_seconds:.1f} s")
    failed = sum(r["failed_turns"] for r in rows)
    if failed:
        click.echo(f"{failed} turn(s) were not written because the model's reply stayed invalid; "
                   f"see `memora stats {bank} --calls failed`", err=True)


@main.command()
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--fts", is_flag=True, help="Full-text indexes: the 'fts' and 'kuzu' retrieval recipes (and 'hnsw').")
@click.option("--hnsw", is_flag=True, help="HNSW vector indexes on segments and entities: the 'hnsw' recipe.")
@click.option("--participants", default="all", show_default=True, help="Comma-separated ids (P01,P02) or 'all'.")
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
    from memora_graph.bank import Bank, parse_participants

    if not (fts or hnsw):
        raise click.UsageError("say which indexes to build: --fts and/or --hnsw")
    pids = parse_participants(participants)
    done = Bank(bank).build_indexes(pids, fts=fts, hnsw=hnsw)
    rows = [{"participant": p, "created": ", ".join(r["created"]) or "(had them)", "indexes": ", ".join(r["indexes"]),
             "seconds": round(r["seconds"], 1)} for p, r in done.items()]
    click.echo(render(pl.DataFrame(rows), fmt))


@main.command()
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.argument("cypher")
@param_option
@click.option("--participant", help="Only this participant's database (default: every participant, concatenated).")
@click.option("--write", is_flag=True, help="Allow data writes (CREATE, MERGE, SET, DELETE, REMOVE) to the one "
                                            "--participant; never files, extensions or the schema.")
@click.option("--timeout", type=float, default=30.0, show_default=True, metavar="SECONDS",
              help="Stop the query after this long.")
@output_options
def query(bank, cypher, params, participant, write, timeout, fmt):
    """Run one ad-hoc Cypher statement over a bank (read-only unless --write).

    The statement must be one read query (MATCH, OPTIONAL MATCH, UNWIND, WITH, RETURN, or CALL of
    a read-only procedure such as show_tables); COPY, LOAD, EXPORT, ATTACH, extensions, schema
    and transaction statements are refused before anything runs. $participant is bound to the
    participant whose database is read unless -p participant says otherwise.

    \b
    Examples:
      memora query banks/epic "MATCH (p:Place) WHERE p.participant = \\$participant RETURN p.name, p.turn_count" -p participant P01
      memora query banks/epic "MATCH (e:Entity) RETURN e.participant, count(*) AS n" --csv
      memora query banks/epic "CALL show_tables() RETURN name, type" --participant P01
      memora query banks/epic "MATCH (e:Entity {object_id: 'plate'}) SET e.state = 'clean'" --participant P01 --write
    """
    from memora_graph.adhoc import run_query

    click.echo(render(run_query(bank, cypher, _params(params), participant=participant, write=write, timeout=timeout),
                      fmt))


@main.command("queries")
@output_options
def list_queries(fmt):
    """List the named queries with their parameters and descriptions.

    \b
    Example:
      memora queries
    """
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
      memora run banks/epic object_history -p participant P01 -p object plate
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


@main.group()
def perf():
    """Benchmarks that print their figures (not timed tests)."""


@perf.command("build")
@click.option("--bank", "bank_dir", type=click.Path(file_okay=False), help="Where to build (default: a temporary directory).")
@click.option("--participants", default="all", show_default=True)
@click.option("--episodic", is_flag=True, help="Time the MEMORA-Episodic build (no consolidation).")
@click.option("--fts", is_flag=True, help="Time the build with the full-text indexes (`memora build --fts`).")
@click.option("--jobs", type=click.IntRange(min=1), default=None, help="Worker processes (default: as `memora build`).")
def perf_build(bank_dir, participants, episodic, fts, jobs):
    """Build the bundled annotations from scratch and print where the time went: every phase,
    summing to the wall time (to worker-seconds with --jobs > 1), and the share of graph work
    (all but embedding and model load).

    \b
    Example:
      memora perf build
    """
    import os
    import tempfile

    from memora_graph.bank import parse_participants
    from memora_graph.pipeline import build_bank

    pids = parse_participants(participants)
    load_before = os.getloadavg()
    others = _OtherCPU()
    with tempfile.TemporaryDirectory() as tmp:
        res = build_bank(bank_dir or f"{tmp}/bank", pids, episodic=episodic, fts=fts, jobs=jobs)
    others_s = others.seconds()
    total = res.wall_seconds
    phases = res.phases()
    capacity = res.jobs * total  # seconds the phases add up to: the wall time, or worker-seconds
    rows = [{"phase": k, "seconds": round(v, 2), "share%": round(100 * v / capacity, 1) if capacity else 0.0}
            for k, v in phases.items()]
    rows.append({"phase": "sum of phases", "seconds": round(sum(phases.values()), 2),
                 "share%": round(100 * sum(phases.values()) / capacity, 1) if capacity else 0.0})
    click.echo(render(pl.DataFrame(rows)))
    if res.jobs > 1:
        click.echo(f"{res.jobs} worker processes: the phases are worker-seconds, summing to {res.jobs} x wall")
    click.echo(f"participants {len(res.participants)}  segments {res.segments}  wall {total:.1f} s  "
               f"segments/s {res.segments / total:.0f}  texts encoded {res.texts_encoded}  encode calls by torch "
               f"threads {dict(sorted(res.embed_threads.items()))}")
    click.echo(f"machine: load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}"
               + (f"; during the build other processes used {others_s[0]:.1f} CPU-seconds and the hypervisor took "
                  f"{others_s[1]:.1f} (steal)" if others_s is not None else ""))
    of = "wall" if res.jobs == 1 else f"the workers' busy {res.busy_seconds:.1f} s"
    click.echo(f"graph work (all but embedding {res.embedding_seconds:.1f} s and model load {res.model_seconds:.1f} s): "
               f"{res.graph_seconds:.1f} s = {100 * res.graph_share:.0f}% of {of} (target <= 25%; wall {total:.1f} s, "
               f"target <= 120 s)")


class _OtherCPU:
    """CPU seconds other processes used while this one ran (Linux /proc/stat busy time minus our
    own) and the hypervisor took from this virtual machine (steal), to tell a clean timing from
    one taken on a shared machine."""

    def __init__(self):
        self._start = self._sample()

    @staticmethod
    def _sample() -> tuple[float, float, float] | None:
        import os
        import resource

        try:
            with open("/proc/stat") as fh:
                f = [int(x) for x in fh.readline().split()[1:9]] + [0]
        except (OSError, ValueError):
            return None
        me = resource.getrusage(resource.RUSAGE_SELF)
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)
        own = me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime
        tick = os.sysconf("SC_CLK_TCK")
        return (f[0] + f[1] + f[2] + f[5] + f[6]) / tick, own, f[7] / tick

    def seconds(self) -> tuple[float, float] | None:
        """(other processes' CPU-seconds, steal seconds) since construction."""
        end = self._sample()
        if self._start is None or end is None:
            return None
        return max((end[0] - self._start[0]) - (end[1] - self._start[1]), 0.0), end[2] - self._start[2]


def _register_perf_video() -> None:
    from memora_graph.perf_video import perf_decode, perf_video

    perf.add_command(perf_decode)
    perf.add_command(perf_video)
    from memora_graph.perf_ray import perf_ray

    perf.add_command(perf_ray)  # memora perf ray: the Ray executor's overhead, side by side


_register_perf_video()


def _register_optional_groups() -> None:
    from memora_graph.agent.cli import ask_cmd
    from memora_graph.bench.cli import bench_group
    from memora_graph.consolidate.cli import consolidate_cmd
    from memora_graph.explore.cli import explore_cmd
    from memora_graph.retrieve.cli import perf_tools_cmd, tool_cmd, tools_cmd
    from memora_graph.retrieve.perf_encoders import perf_encoders_cmd
    from memora_graph.transfer.cli import export_cmd, import_cmd

    main.add_command(consolidate_cmd, "consolidate")
    for cmd in (explore_cmd, export_cmd, import_cmd):  # memora explore / export / import
        main.add_command(cmd)
    main.add_command(tools_cmd, "tools")
    main.add_command(tool_cmd, "tool")
    perf.add_command(perf_tools_cmd, "tools")
    perf.add_command(perf_encoders_cmd, "encoders")
    main.add_command(ask_cmd, "ask")
    main.add_command(bench_group, "bench")


_register_optional_groups()


def _register_integrity() -> None:
    from memora_graph.integrity.cli import register

    register(main)  # verify, forget, and --no-verify on every command that opens a bank (last: it sees them all)


_register_integrity()

if __name__ == "__main__":
    sys.exit(main())

"""`memora perf live`: live memory on a memory of 10, 100 (1,000) hours.

For each size, a copy of a bank holding that much prior memory of one participant (built here
from a synthesized long-horizon participant, `memora bench synth` + `memora build`, unless given
with `--bank HOURS=PATH`) is served writable in this process (`MemoryService(..., writable=True)`,
what `memora serve --writable` runs) and measured:

- remember latency (p50 / p95, wall and CPU) of `--remembers` narrations of the participant's
  own EPIC annotations replayed as a new video, through the MCP tool's code path (perceive, embed,
  edit, commit, readers' caches updated);
- tool latency (every retrieval tool but `cypher`, in process) idle, then while a thread
  remembers at `--rate` per second; the ratio of the p95s (target <= 2);
- incremental consolidation: a first run (every video), then the time per 100 new segments
  (`--no-consolidation` skips it: while it recomputes the whole memory it takes most of the
  run at 1,000 h).

On a shared machine wall times include waiting for a core; CPU time (this process, all threads)
does not; each row records the load average at its start and end. Each size's result is saved as JSON in the work folder and reused by a later run.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import threading
import time
from pathlib import Path

import click
import polars as pl

from memora_graph.cli.form import checkpoint_options, checkpoint_policy
from memora_graph.output import render

TARGET_P50_MS, TARGET_P95_MS, TARGET_RATIO = 20.0, 50.0, 2.0
TARGET_READ_MS = 200.0  # ask, plan and every named query, idle and while remembering (p95)
SKIP_TOOLS = ("cypher",)  # a child process per call in a read-only server; its own benchmark is `perf serve`


def _pct(xs: list[float], p: float) -> float:
    xs = sorted(xs)
    return round(xs[min(len(xs) - 1, max(0, int(round(p * (len(xs) - 1)))))], 2) if xs else float("nan")


def _load() -> float | None:
    """The machine's 1-minute load average (wall times on a shared machine are read against it)."""
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def _narrations(participant: str, n: int) -> list[str]:
    """The participant's own narrations (bundled EPIC annotations), in order, `n` of them."""
    from memora_graph.perceive.annotations import load_annotations

    texts = load_annotations(participants=[participant])["narration"].to_list()
    return [texts[i % len(texts)] for i in range(n)]


def prepare_bank(participant: str, hours: float, work: Path, given: str | None, echo) -> Path:
    """The bank of `hours` prior memory: `given` (copied), or synthesized and built once in `work`."""
    tag = f"{hours:g}h"
    base = work / f"base-{tag}"
    if given:
        return Path(given)
    if not (work / f"base-{tag}.done").exists():
        from memora_graph.bench.synth import synthesize
        from memora_graph.pipeline import build_bank

        if base.exists():
            shutil.rmtree(base)
        synth = work / f"synth-{tag}"
        if not (synth / "synth.json").exists():
            echo(f"synthesizing {tag} of {participant}")
            synthesize(participant, hours, synth)
        echo(f"building {tag} (once; kept in {base})")
        build_bank(base, [participant], synth / "annotations.csv", jobs=1)
        (work / f"base-{tag}.done").touch()
    return base


def _read_figures(idle_by: dict[str, list[float]], busy_by: dict[str, list[float]]) -> dict:
    """The figures the read targets name: `ask` and `plan` p95, idle and while remembering, and
    the slowest named query (a `query_*` tool) with its p95 (targets: <= 200 ms each)."""
    out = {}
    for tool in ("ask", "plan"):
        if tool in idle_by:
            out[f"{tool}_idle_p95_ms"] = _pct(idle_by[tool], .95)
            out[f"{tool}_stream_p95_ms"] = _pct(busy_by.get(tool, [0.0]), .95)
    named = {n: max(_pct(v, .95), _pct(busy_by.get(n, [0.0]), .95)) for n, v in idle_by.items() if n.startswith("query_")}
    if named:
        worst = max(named, key=named.get)
        out.update(named_query_worst=worst, named_query_worst_p95_ms=named[worst],
                   named_queries_over_target=sorted(n for n, v in named.items() if v > TARGET_READ_MS))
    return out


def _peak_rss_mb() -> float:
    """This process's peak resident memory so far (MB)."""
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def measure(bank: Path, participant: str, remembers: int, rate: float, tool_rounds: int, echo,
            consolidation: bool = True, checkpoint=None) -> dict:
    from memora_graph.form.live import Moment
    from memora_graph.serve import MemoryService
    from memora_graph.cli.perf.serve import call_set

    texts = _narrations(participant, 2000)
    t0, c0 = time.perf_counter(), time.process_time()
    service = MemoryService(bank, participant, writable=True, checkpoint=checkpoint)  # stores written first if stale
    opened = {"open_s": round(time.perf_counter() - t0, 2), "open_cpu_s": round(time.process_time() - c0, 2),
              "tool_stores": "written" if service._views[participant].persisted_written else
              ("read" if service._views[participant]._persisted is not None else "none (Kùzu)")}
    counts = service.bank.manifest()["participants"][participant]["counts"]
    out = {"segments_before": counts.get("segments"), "state_events_before": counts.get("state_events"),
           "load_start": _load(), **opened}
    step = [0]

    def remember() -> tuple[float, float]:
        """Wall and CPU ms of one remember (CPU of the whole process: Kùzu's and torch's threads too,
        which is the remember's own cost while nothing else runs in the process)."""
        i = step[0]
        step[0] += 1
        m = Moment("live-perf", 3.0 * i, 3.0 * i + 2.5, texts[i % len(texts)])
        t0, c0 = time.perf_counter(), time.process_time()
        service.call("remember", {"text": m.text, "video": m.video, "start": m.start, "end": m.end})
        return (time.perf_counter() - t0) * 1e3, (time.process_time() - c0) * 1e3

    try:
        calls = [(n, a) for n, a in call_set(service, participant) if n not in SKIP_TOOLS]
        for name, args in calls:  # warm: every table and vector loaded, the query encoder ready
            service.call(name, args)
        for _ in range(5):
            remember()  # warm: the writer's statements prepared
        echo(f"  {remembers} remembers")
        wall, cpu = zip(*[remember() for _ in range(remembers)])
        out.update(remember_p50_ms=_pct(wall, .5), remember_p95_ms=_pct(wall, .95), remember_cpu_p50_ms=_pct(cpu, .5),
                   remember_cpu_p95_ms=_pct(cpu, .95), remember_p99_ms=_pct(wall, .99),
                   remember_max_ms=round(max(wall), 2))
        # the writer's checkpoints meanwhile (form/checkpoint.py): how many, and how long each held the writer
        runs = [r for r in service.writer.checkpointer.runs if r["ok"]]
        out.update(checkpoints=len(runs), checkpoint_max_s=round(max((r["seconds"] for r in runs), default=0.0), 2),
                   checkpoint_policy=service.writer.checkpoint_policy.describe())

        def tool_times(rounds: int, by_tool: dict | None = None) -> list[float]:
            got = []
            for _ in range(rounds):
                for name, args in calls:
                    t0 = time.perf_counter()
                    service.call(name, args)
                    got.append((time.perf_counter() - t0) * 1e3)
                    if by_tool is not None:
                        by_tool.setdefault(name, []).append(got[-1])
            return got

        echo("  tools idle")
        idle_by, busy_by = {}, {}
        idle = tool_times(tool_rounds, idle_by)
        stop = threading.Event()
        streamed = []

        def stream() -> None:
            period = 1.0 / rate
            nxt = time.perf_counter()
            while not stop.is_set():
                streamed.append(remember()[0])
                nxt += period
                time.sleep(max(0.0, nxt - time.perf_counter()))

        echo(f"  tools while remembering {rate:g}/s")
        t = threading.Thread(target=stream, daemon=True)
        t0 = time.perf_counter()
        t.start()
        busy = tool_times(tool_rounds, busy_by)
        stop.set()
        t.join()
        achieved = len(streamed) / (time.perf_counter() - t0)
        out.update(tool_idle_p50_ms=_pct(idle, .5), tool_idle_p95_ms=_pct(idle, .95), tool_stream_p50_ms=_pct(busy, .5),
                   tool_stream_p95_ms=_pct(busy, .95), stream_rate_achieved=round(achieved, 2),
                   stream_remember_p95_ms=_pct(streamed, .95), tool_calls=len(idle))
        out["tool_p95_ratio"] = round(out["tool_stream_p95_ms"] / out["tool_idle_p95_ms"], 2)
        out["tool_idle_p95_by_tool_ms"] = {n: _pct(v, .95) for n, v in sorted(idle_by.items())}
        out["tool_stream_p95_by_tool_ms"] = {n: _pct(v, .95) for n, v in sorted(busy_by.items())}
        out.update(_read_figures(idle_by, busy_by))
        echo("  " + json.dumps(out))
        if not consolidation:
            return out

        echo("  incremental consolidation")
        from memora_graph.consolidate.live import BackgroundConsolidation

        cons = BackgroundConsolidation(service.writer, every=10**9, lock=service.write_locks(),
                                       on_done=service._consolidated)
        try:
            t0, c0 = time.perf_counter(), time.process_time()
            cons.run_once()
            out.update(consolidate_first_s=round(time.perf_counter() - t0, 2),
                       consolidate_first_cpu_s=round(time.process_time() - c0, 2))
            per100 = []
            for _ in range(2):
                for _ in range(100):
                    remember()
                t0, c0 = time.perf_counter(), time.process_time()
                cons.run_once(100)
                per100.append((time.perf_counter() - t0, time.process_time() - c0))
            out.update(consolidate_per_100_s=round(statistics.median(w for w, _ in per100), 2),
                       consolidate_per_100_cpu_s=round(statistics.median(c for _, c in per100), 2),
                       consolidate_videos_reused=cons.state.reused, consolidate_videos_recomputed=cons.state.recomputed,
                       consolidate_last_run={k: v for k, v in cons.runs[-1].items() if k != "new_segments"})
        finally:
            cons.stop()
    finally:
        service.close()
        out["load_end"] = _load()
        out["peak_rss_mb"] = _peak_rss_mb()
    return out


def reopen_figures(bank: Path, participant: str, checkpoint=None) -> dict:
    """After the remembers above: opening the participant writable again (what `memora serve
    --writable` pays at a restart), and read-only (the first read of another process after a
    batch of remembers), each with its first `ask`; whether the tool stores were written again
    (a full rewrite), read with the journal of remembered moments, or read as they were."""
    from memora_graph.serve import MemoryService

    question = {"question": "Where is the knife?"}
    out = {}
    for tag, writable in (("reopen_writable", True), ("first_read", False)):
        t0, c0 = time.perf_counter(), time.process_time()
        service = MemoryService(bank, participant, writable=writable,
                                **({"checkpoint": checkpoint} if writable else {}))
        try:
            out[f"{tag}_s"] = round(time.perf_counter() - t0, 2)
            out[f"{tag}_cpu_s"] = round(time.process_time() - c0, 2)
            view = service._views[participant]
            replayed = view.__dict__.get("replayed")
            out[f"{tag}_stores"] = "written" if view.persisted_written else (
                f"read + {replayed[0]} journaled moments" if replayed else
                "read" if view._persisted is not None else "none (Kùzu)")
            t0 = time.perf_counter()
            service.call("ask", question)
            out[f"{tag}_first_ask_s"] = round(time.perf_counter() - t0, 3)
        finally:
            service.close()
    return out


def run_live(participant: str, sizes: list[float], work: Path, banks: dict[float, str], remembers: int, rate: float,
             tool_rounds: int, echo=print, consolidation: bool = True, checkpoint=None) -> list[dict]:
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for hours in sizes:
        tag = f"{hours:g}h"
        saved = work / f"live-{tag}.json"
        if saved.exists():
            rows.append(json.loads(saved.read_text()))
            continue
        base = prepare_bank(participant, hours, work, banks.get(hours), echo)
        run = work / f"run-{tag}"
        if run.exists():
            shutil.rmtree(run)
        shutil.copytree(base, run)  # the measured writes never touch the base (or a given) bank
        echo(f"{tag}: measuring on {run}")
        row = {"hours": hours, **measure(run, participant, remembers, rate, tool_rounds, echo, consolidation,
                                         checkpoint)}
        echo("  opens after the remembers")
        row.update(reopen_figures(run, participant, checkpoint))
        row["peak_rss_mb"] = _peak_rss_mb()
        saved.write_text(json.dumps(row))
        rows.append(row)
        shutil.rmtree(run, ignore_errors=True)
    return rows


@click.command("live")
@click.option("--participant", default="P01", show_default=True, help="Whose memory is synthesized and replayed.")
@click.option("--sizes", default="10,100", show_default=True, help="Hours of prior memory, comma-separated.")
@click.option("--work", type=click.Path(file_okay=False), default="perf-live", show_default=True,
              help="Work folder: banks built once, and each size's result (reused by a later run).")
@click.option("--bank", "banks", multiple=True, metavar="HOURS=PATH",
              help="Use an existing bank for a size instead of building one (copied; never written).")
@click.option("--remembers", type=click.IntRange(min=10), default=200, show_default=True,
              help="Remembers timed one after another.")
@click.option("--rate", type=float, default=10.0, show_default=True, help="Remembers per second during the tool test.")
@click.option("--tool-rounds", type=click.IntRange(min=1), default=3, show_default=True,
              help="Rounds of every tool call, idle and while remembering.")
@click.option("--consolidation/--no-consolidation", default=True, show_default=True,
              help="Measure incremental consolidation (a first run, then two of 100 new segments each). It "
                   "recomputes the whole memory per run, so at 1,000 h it is most of the run's time: "
                   "--no-consolidation measures remember and the tools only.")
@click.option("--json", "as_json", is_flag=True, help="Print the rows as JSON.")
@checkpoint_options
def perf_live_cmd(participant, sizes, work, banks, remembers, rate, tool_rounds, consolidation, as_json, checkpoint_mb,
                  checkpoint_moments, checkpoint_seconds):
    """Live memory: remember latency, tool latency while remembering, incremental consolidation.

    \b
    Targets: remember p50 <= 20 ms and p95 <= 50 ms; tool p95 while remembering at 10/s <= 2x idle;
    ask, plan and every named query p95 <= 200 ms, idle and while remembering.
    Examples:
      memora perf live --sizes 10 --work /tmp/perf-live
      memora perf live --sizes 10,100 --bank 10=/path/to/bank-10h --remembers 300 --json
      memora perf live --sizes 1000 --bank 1000=/path/to/bank-1000h --no-consolidation
      memora perf live --sizes 10 --remembers 1000 --no-consolidation --checkpoint-mb 0 --checkpoint-moments 0
    """
    given: dict[float, str] = {}
    for b in banks:
        hours, _, path = b.partition("=")
        try:
            given[float(hours)] = path
        except ValueError:
            raise click.UsageError(f"--bank {b}: expected HOURS=PATH") from None
    try:
        hours = [float(s) for s in sizes.split(",") if s.strip()]
    except ValueError:
        raise click.UsageError(f"--sizes {sizes}: expected hours like 10,100") from None
    rows = run_live(participant, hours, Path(work), given, remembers, rate, tool_rounds,
                    echo=lambda s: click.echo(s, err=True), consolidation=consolidation,
                    checkpoint=checkpoint_policy(checkpoint_mb, checkpoint_moments, checkpoint_seconds))
    if as_json:
        click.echo(json.dumps(rows, indent=2))
        return
    click.echo(render(pl.DataFrame([{k: v for k, v in r.items() if not isinstance(v, dict)} for r in rows])))
    for r in rows:
        cons = (f"incremental consolidation {r['consolidate_per_100_s']} s per 100 new segments (first run "
                f"{r['consolidate_first_s']} s)" if "consolidate_per_100_s" in r else "consolidation not measured")
        ok = r["remember_p50_ms"] <= TARGET_P50_MS and r["remember_p95_ms"] <= TARGET_P95_MS
        click.echo(f"{r['hours']:g} h: remember p50 {r['remember_p50_ms']} ms / p95 {r['remember_p95_ms']} ms "
                   f"(CPU {r['remember_cpu_p50_ms']} / {r['remember_cpu_p95_ms']}) {'meets' if ok else 'misses'} "
                   f"<= {TARGET_P50_MS:g} / {TARGET_P95_MS:g}; tool p95 while remembering {r['tool_p95_ratio']}x idle "
                   f"(target <= {TARGET_RATIO:g}); {cons}; load average {r.get('load_start')} "
                   f"-> {r.get('load_end')}")
        if "reopen_writable_s" in r:
            click.echo(f"{r['hours']:g} h: after the remembers, a writable open {r['reopen_writable_s']} s "
                       f"(first ask {r['reopen_writable_first_ask_s']} s; stores {r['reopen_writable_stores']}), "
                       f"a read-only open {r['first_read_s']} s (first ask {r['first_read_first_ask_s']} s; "
                       f"stores {r['first_read_stores']}); target <= 2 s; peak RSS {r.get('peak_rss_mb')} MB")
        if "ask_idle_p95_ms" in r:
            click.echo(f"{r['hours']:g} h: open {r['open_s']} s; ask p95 {r['ask_idle_p95_ms']} / "
                       f"{r['ask_stream_p95_ms']} ms idle / while remembering, plan {r.get('plan_idle_p95_ms')} / "
                       f"{r.get('plan_stream_p95_ms')} ms; slowest named query {r.get('named_query_worst')} "
                       f"{r.get('named_query_worst_p95_ms')} ms (target <= {TARGET_READ_MS:g} ms each; over it: "
                       f"{', '.join(r.get('named_queries_over_target') or []) or 'none'})")

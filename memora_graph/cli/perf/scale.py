"""`memora perf scale`: how one person's memory behaves as it grows (10, 100, 1,000 hours).

For each size a long-horizon participant is synthesized (`memora bench synth`: their videos
replayed with renamed objects and reordered actions) and built from scratch, and the bank is
measured: build seconds (wall and CPU) per hour of video, bank size on disk, the peak resident
memory of the build process, the Kùzu FTS + HNSW index build, and for each retrieval recipe
("inprocess": exact numpy top-k + in-process BM25; "hnsw": Kùzu's HNSW and FTS indexes) the
time to open a participant and warm it, p50/p95 per tool (cold: a query never embedded before
in the process; warm: its embedding cached) and the peak resident memory of that process.
Every step runs in its own child process, so its peak RSS is its own.

Each finished step is saved as JSON under the work folder and reused by a later run with the
same folder, so sizes can be run in steps (`--sizes 10,100`, then `--sizes 1000` in the
background) and reported together. The crossover is the smallest measured size at which the
HNSW recipe's median tool p50 is below the in-process recipe's; `HNSW_MIN_SEGMENTS` in
`memora_graph/retrieve/search.py` is set from it and applied when a participant's view opens.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import click
import polars as pl

from memora_graph.output import render

RECIPES = ("inprocess", "hnsw")


def _fmt_size(hours: float) -> str:
    return f"{hours:g}h"


def _dir_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def _child(args: list[str], log: Path) -> dict:
    """Run `python -m memora_graph.cli.perf.scale ARGS` to completion; its wall, CPU and peak RSS
    (os.wait4: this child alone), and the JSON it printed last."""
    t0 = time.perf_counter()
    with log.open("a") as fh:
        proc = subprocess.Popen([sys.executable, "-m", "memora_graph.cli.perf.scale", *args], stdout=subprocess.PIPE,
                                stderr=fh, text=True)
        out = proc.stdout.read()
        _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise click.ClickException(f"step `{' '.join(args)}` failed with exit code {code}; see {log}")
    result = json.loads(out.strip().splitlines()[-1])
    # the child's own peak (VmHWM); wait4's ru_maxrss would count this process's pages it was forked with
    result.update(wall_s=round(wall, 2), cpu_s=round(usage.ru_utime + usage.ru_stime, 2),
                  peak_rss_mb=result.pop("vm_hwm_mb", None) or round(usage.ru_maxrss / 1024, 1))
    return result


def _peak_rss_mb() -> float | None:
    """This process's peak resident memory since it started (exec), from /proc (Linux)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        pass
    return None


def _step(work: Path, name: str, args: list[str], echo) -> dict:
    """A step's saved result, or run it and save it (a later run with this folder reuses it)."""
    saved = work / f"{name}.json"
    if saved.exists():
        echo(f"{name}: reusing {saved}")
        return json.loads(saved.read_text())
    echo(f"{name}: running ...")
    result = _child(args, work / "steps.log")
    tmp = saved.with_suffix(".partial")
    tmp.write_text(json.dumps(result, indent=1))
    os.replace(tmp, saved)
    echo(f"{name}: {result['wall_s']:.1f} s wall, {result['cpu_s']:.1f} CPU-s, peak RSS {result['peak_rss_mb']:.0f} MB")
    return result


def run_scale(participant: str, sizes: list[float], work: Path, seed: int = 0, n_queries: int = 10,
              recipes: tuple[str, ...] = RECIPES, echo=print) -> dict:
    """Synthesize, build, index and measure each size; returns {"sizes": [...], "tools": frame rows}."""
    work.mkdir(parents=True, exist_ok=True)
    _child(["_encoder"], work / "steps.log")  # a first use exports the ONNX query encoder (with torch): not in a step's RSS
    sizes_out, tool_rows = [], []
    for hours in sizes:
        tag = _fmt_size(hours)
        synth_dir, bank = work / f"synth-{tag}", work / f"bank-{tag}"
        if not (synth_dir / "synth.json").exists():
            from memora_graph.bench.synth import synthesize

            synthesize(participant, hours, synth_dir, seed=seed)
        if not (work / f"build-{tag}.json").exists() and bank.exists():
            shutil.rmtree(bank)  # a build this folder did not record as finished starts again
        build = _step(work, f"build-{tag}", ["_build", str(bank), str(synth_dir / "annotations.csv"), participant], echo)
        index = _step(work, f"index-{tag}", ["_index", str(bank), participant], echo)
        stores = _step(work, f"stores-{tag}", ["_stores", str(bank), participant], echo)
        row = {"hours": hours, "segments": build["segments"], "entities": build["entities"],
               "entity_records": build.get("entity_records"),
               "state_events": build["state_events"], "build_s": build["wall_s"], "build_cpu_s": build["cpu_s"],
               "build_s_per_hour": round(build["wall_s"] / hours, 2),
               "build_cpu_s_per_hour": round(build["cpu_s"] / hours, 2), "build_rss_mb": build["peak_rss_mb"],
               "bank_mb": round(build["bank_bytes"] / 1e6, 1), "index_s": index["wall_s"],
               "bank_indexed_mb": round(index["bank_bytes"] / 1e6, 1), "stores_s": stores["wall_s"],
               "stores_cpu_s": stores["cpu_s"], "stores_rss_mb": stores["peak_rss_mb"],
               "stores_mb": round(stores["stores_bytes"] / 1e6, 1)}
        for recipe in recipes:
            q = _step(work, f"tools-{tag}-{recipe}", ["_tools", str(bank), participant, recipe, str(n_queries)], echo)
            row[f"{recipe}_open_s"] = q["open_s"]
            row[f"{recipe}_open_cpu_s"] = q.get("open_cpu_s")
            row[f"{recipe}_reopen_s"] = q.get("reopen_s")
            row[f"{recipe}_reopen_cpu_s"] = q.get("reopen_cpu_s")
            row[f"{recipe}_first_calls_s"] = q.get("first_calls_s")
            row[f"{recipe}_rss_mb"] = q["peak_rss_mb"]
            for tool, t in q["tools"].items():
                tool_rows.append({"hours": hours, "segments": build["segments"], "recipe": recipe, "tool": tool, **t})
            row[f"{recipe}_tool_p50_median_ms"] = round(statistics.median(t["cold_p50_ms"] for t in q["tools"].values()), 2)
            row[f"{recipe}_tool_p95_median_ms"] = round(statistics.median(t["cold_p95_ms"] for t in q["tools"].values()), 2)
            row[f"{recipe}_tool_p95_max_ms"] = round(max(t["cold_p95_ms"] for t in q["tools"].values()), 2)
            if all("cold_cpu_p50_ms" in t for t in q["tools"].values()):
                row[f"{recipe}_tool_cpu_p50_median_ms"] = round(
                    statistics.median(t["cold_cpu_p50_ms"] for t in q["tools"].values()), 2)
            if all("cold_cpu_p95_ms" in t for t in q["tools"].values()):
                row[f"{recipe}_tool_cpu_p95_median_ms"] = round(
                    statistics.median(t["cold_cpu_p95_ms"] for t in q["tools"].values()), 2)
        sizes_out.append(row)
    return {"participant": participant, "sizes": sizes_out, "tools": tool_rows, "crossover": crossover(sizes_out)}


def crossover(sizes: list[dict]) -> dict | None:
    """The smallest measured size at which the HNSW recipe is faster than the in-process one (the
    median over the tools of their p50, which a shared machine disturbs less than p95), with the
    largest size below it that was not (the threshold lies between). Faster means in wall time
    and in CPU time both, where CPU was measured: Kùzu runs an HNSW query on several threads, so
    on an idle test machine it can win on wall time while costing more CPU, which a machine
    running other work (an evaluation's workers, an agent) pays for."""
    below = None
    for row in sorted(sizes, key=lambda r: r["hours"]):
        a, b = row.get("inprocess_tool_p50_median_ms"), row.get("hnsw_tool_p50_median_ms")
        if a is None or b is None:
            continue
        ca, cb = row.get("inprocess_tool_cpu_p50_median_ms"), row.get("hnsw_tool_cpu_p50_median_ms")
        if b < a and (ca is None or cb is None or cb < ca):
            return {"hours": row["hours"], "segments": row["segments"],
                    "slower_below": None if below is None else {"hours": below["hours"], "segments": below["segments"]}}
        below = row
    return None


# -- the steps, each in its own process ------------------------------------------------------------
def _build_step(bank: str, annotations: str, participant: str) -> dict:
    from memora_graph.pipeline import build_bank

    res = build_bank(bank, [participant], annotations, jobs=1)
    counts = res.participants[0].counts
    return {"segments": counts.get("segments"), "entities": counts.get("entities"),
            "entity_records": counts.get("entity_records"),
            "state_events": counts.get("state_events"), "videos": counts.get("videos"),
            "embedding_s": round(res.embedding_seconds, 2), "model_load_s": round(res.model_seconds, 2),
            "bank_bytes": _dir_bytes(Path(bank))}


def _index_step(bank: str, participant: str) -> dict:
    from memora_graph.bank import Bank

    Bank(bank).build_indexes([participant], fts=True, hnsw=True)  # as `memora index BANK --fts --hnsw`
    return {"bank_bytes": _dir_bytes(Path(bank))}


def _stores_step(bank: str, participant: str) -> dict:
    """The tool stores persisted next to the bank (as `memora build` and `memora index` write them)."""
    from memora_graph.retrieve.view import persist_bank

    done = persist_bank(bank, [participant])
    return {"stores_bytes": sum(_dir_bytes(Path(d)) for d in done.written)}


def _tools_step(bank: str, participant: str, recipe: str, n_queries: int) -> dict:
    from memora_graph.embed import get_embedder
    from memora_graph.cli.perf.tools import TOOLS, percentile, tool_queries, timed_ms
    from memora_graph.retrieve.registry import call_tool
    from memora_graph.retrieve.view import MemoryView

    embedder = get_embedder()
    embedder.inner.encode(["warm up"], kind="query")  # the model load is not the bank's open time
    t0, c0 = time.perf_counter(), time.process_time()
    view = MemoryView.open(bank, participant, embedder, config=recipe)
    try:
        view.warm()
        open_s, open_cpu_s = time.perf_counter() - t0, time.process_time() - c0
        t1 = time.perf_counter()
        for tool in TOOLS:  # one untimed call each: prepared statements, lazily loaded tables
            call_tool(view, tool, tool_queries(tool, view, 1)[0])
        first_calls_s = time.perf_counter() - t1
        out = {}
        for tool in TOOLS:
            cold, cold_cpu, warm = [], [], []
            for args in tool_queries(tool, view, n_queries):
                view.encoder.clear(everywhere=True)
                cold.append(timed_ms(lambda: call_tool(view, tool, args), cold_cpu))
                warm.append(timed_ms(lambda: call_tool(view, tool, args)))
            out[tool] = {"calls": len(cold), "cold_p50_ms": round(percentile(cold, .5), 2),
                         "cold_p95_ms": round(percentile(cold, .95), 2), "cold_cpu_p50_ms": round(percentile(cold_cpu, .5), 2),
                         "cold_cpu_p95_ms": round(percentile(cold_cpu, .95), 2), "warm_p50_ms": round(percentile(warm, .5), 2),
                         "warm_p95_ms": round(percentile(warm, .95), 2)}
    finally:
        view.close()
    # opened again: the first open after the stores were written hashes them (and records that it
    # did, persist.py); a later open checks their stat instead
    t2, c2 = time.perf_counter(), time.process_time()
    with MemoryView.open(bank, participant, embedder, config=recipe) as again:
        again.warm()
        reopen_s, reopen_cpu_s = time.perf_counter() - t2, time.process_time() - c2
    return {"open_s": round(open_s, 3), "open_cpu_s": round(open_cpu_s, 3), "first_calls_s": round(first_calls_s, 3),
            "reopen_s": round(reopen_s, 3), "reopen_cpu_s": round(reopen_cpu_s, 3), "tools": out}


@click.command("scale")
@click.option("--participant", default="P01", show_default=True, help="Whose videos to replay.")
@click.option("--sizes", default="10,100,1000", show_default=True, help="Hours of video, comma-separated.")
@click.option("--work", type=click.Path(file_okay=False, path_type=Path), default=Path("runs/scale"), show_default=True,
              help="Where the synthetic annotations, the banks and each finished step's JSON go; a later run with "
                   "the same folder reuses finished steps (run sizes in steps, large ones in the background).")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--queries", "n_queries", default=10, show_default=True, type=click.IntRange(min=1), help="Calls per tool.")
@click.option("--json", "as_json", is_flag=True, help="Print the figures as JSON.")
def perf_scale_cmd(participant, sizes, work, seed, n_queries, as_json):
    """Build 10, 100 and 1,000 hours of one participant and print, per size: build seconds per
    hour, bank size, open time, peak resident memory, p50/p95 per tool for the in-process and
    the Kùzu HNSW recipes, and the size at which HNSW becomes faster.

    \b
    Examples:
      memora perf scale --sizes 10,100 --work runs/scale
      nohup memora perf scale --sizes 1000 --work runs/scale &     # then:
      memora perf scale --sizes 10,100,1000 --work runs/scale      # reuses the finished steps
    """
    try:
        hours = [float(s) for s in sizes.split(",") if s.strip()]
    except ValueError:
        raise click.BadParameter(f"expected hours such as 10,100,1000 (got {sizes!r})", param_hint="'--sizes'")
    if not hours or any(h <= 0 for h in hours):
        raise click.BadParameter("sizes must be positive hours", param_hint="'--sizes'")
    log = (lambda text: click.echo(text, err=True)) if as_json else click.echo
    res = run_scale(participant.upper(), hours, work, seed=seed, n_queries=n_queries, echo=log)
    if as_json:
        click.echo(json.dumps(res, indent=1))
        return
    click.echo(render(pl.DataFrame(res["sizes"]).transpose(include_header=True, header_name="figure",
                                                           column_names=[_fmt_size(h) for h in hours])))
    tools = pl.DataFrame(res["tools"])
    if not tools.is_empty():
        click.echo(render(tools.select("hours", "recipe", "tool", "cold_p50_ms", "cold_p95_ms", *(
            c for c in ("cold_cpu_p50_ms", "cold_cpu_p95_ms") if c in tools.columns), "warm_p50_ms", "warm_p95_ms")))
    x = res["crossover"]
    from memora_graph.retrieve.search import HNSW_MIN_SEGMENTS

    click.echo("HNSW faster (median over tools of p50, in wall and CPU time) from " + (f"{x['hours']:g} h ({x['segments']} segments)" if x else
               "no measured size") + f"; HNSW_MIN_SEGMENTS = {HNSW_MIN_SEGMENTS}; load average "
               f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


def _main(argv: list[str]) -> None:
    """Child entry: one step, its result as one JSON line on stdout."""
    step, *args = argv
    if step == "_encoder":
        from memora_graph.embed import get_embedder

        get_embedder().inner.encode(["warm up"], kind="query")
        result = {}
    elif step == "_build":
        result = _build_step(*args)
    elif step == "_index":
        result = _index_step(*args)
    elif step == "_stores":
        result = _stores_step(*args)
    elif step == "_tools":
        result = _tools_step(args[0], args[1], args[2], int(args[3]))
    else:
        raise SystemExit(f"unknown step {step}")
    result["vm_hwm_mb"] = _peak_rss_mb()
    sys.stdout.write(json.dumps(result) + "\n")


if __name__ == "__main__":
    _main(sys.argv[1:])

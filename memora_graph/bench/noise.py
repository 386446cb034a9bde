"""Memory under imperfect perception: the noise sweep behind `memora bench noise`.

For every error type and rate (perceive/noise.py), the sweep writes the noisy annotations, builds
the three banks the seven conditions read (MEMORA, raw, MEMORA-Episodic) from them, runs the
evaluation with `bench/run.py` (`run_bench`, resumable item by item), and reads off the curves:

    OUT/noise.json                 the sweep's options (participants, rates, errors, seed, delta)
    OUT/cells/<error>-<rate>/      one cell: annotations/ (with errors.jsonl, the error log),
                                   banks/{edited,raw,episodic}/, run/ (a `bench run` directory:
                                   `memora bench compare` reads two of them), repair.json
    OUT/curves.parquet             one row per (error, rate, condition): EAM-QA accuracy, RGP
    OUT/repair.parquet             the editor's repair table per cell
    OUT/figures/*.png              accuracy and RGP against rate, one panel per error type
    OUT/report.md, OUT/report.json break-even rates, processed vs raw, the repair table

Rate 0 is one shared clean cell (`clean-0`) for every error type. The noisy annotations of every
cell are written first (seconds); then the cells run side by side in `jobs` long-lived worker
processes (default one per core), each building a cell's three banks (with the persisted tool
stores that `memora build` writes, for the two banks MEMORA reads) and reading them in-process
with one reader, so the embedding model, the reader and the tool stores load once per worker, not
once per bank and run process. Cells run coarse to fine (`coarse_first`): a sweep stopped early
has a coarse curve in every panel. Each build and each run starts from an empty embedding cache
(`clear_embedding_caches`): a vector's last bits depend on the other texts of its batch, and
vectors kept from another bank or cell changed a few tool results' last digit, so a cell's
records are those of its banks built by `memora build` and read by `bench run`, one by one (within
a cell, a list of texts the model embedded before is not embedded again: `embed.same_batches`,
the same vectors bit for bit; the three banks share their segments' texts). A cell
whose banks and run are complete is skipped; an interrupted one resumes (its build and its run
both resume). Each cell appends its wall and CPU-seconds to its `timing.jsonl`.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from statistics import mean
from typing import Any, Callable

import polars as pl

from memora_graph.bank import Bank
from memora_graph.bench.aggregate import eam_scores, planning_panel
from memora_graph.bench.conditions import resolve_conditions
from memora_graph.bench.items import KINDS
from memora_graph.bench.run import load_run, resolve_workers, run_bench, split_conditions
from memora_graph.embed import clear_embedding_caches, same_batches
from memora_graph.errors import MemoraError
from memora_graph.form.repair import REPAIRS_ENV
from memora_graph.perceive.annotations import load_annotations, load_class_tables, load_video_info, noun_phrase
from memora_graph.perceive.narration import slug
from memora_graph.perceive.noise import ERROR_TYPES, MIXED, NoiseSpec, inject_noise, read_errors, verb_families, write_noisy
from memora_graph.perceive.vocab import VERB_STATE

MEMORA, EPISODIC, PARAMETRIC = "memora_full", "memora_episodic", "no_memory"
BASELINES = ("flat_1d_raw", "flat_1d_edited", "graph_2d_raw", "graph_2d_edited")
SWEEP_ERRORS = (MIXED, *ERROR_TYPES)
BANKS = {"edited": dict(mode="edited"), "raw": dict(mode="raw"), "episodic": dict(mode="edited", episodic=True)}
TOOL_BANKS = ("edited", "episodic")  # the banks MEMORA's tools read (the raw bank: the raw baselines only)


@dataclass
class NoiseSweep:
    out: Path
    cells: list[dict] = field(default_factory=list)  # one per (error, rate): seconds, CPU-seconds
    seconds: float = 0.0
    cpu_seconds: float = 0.0  # this process and its workers
    jobs: int = 1


def cell_name(error: str, rate: float) -> str:
    return "clean-0" if rate == 0 else f"{error}-{rate:g}"


def parse_rates(text: str) -> list[float]:
    try:
        rates = sorted({float(x) for x in text.split(",") if x.strip()})
    except ValueError:
        raise MemoraError(f"--rates {text!r}: rates are numbers between 0 and 1, comma-separated") from None
    if not rates or any(not 0 <= r <= 1 for r in rates):
        raise MemoraError(f"--rates {text!r}: give at least one rate, each between 0 and 1")
    return rates


def parse_errors(text: str) -> list[str]:
    errors = list(dict.fromkeys(x.strip() for x in text.split(",") if x.strip()))
    bad = [e for e in errors if e not in SWEEP_ERRORS]
    if bad or not errors:
        raise MemoraError(f"--errors {text!r}: choose from {', '.join(SWEEP_ERRORS)}")
    return errors


def run_noise(out: str | Path, participants: list[str], rates: list[float], errors: list[str], *,
              conditions: str | list[str] = "all", seed: int = 0, delta: float = 5.0, kinds: tuple[str, ...] = KINDS,
              limit: int | None = None, workers: int | None = None, jobs: int | None = None, annotations: str | Path | None = None,
              repairs: bool = False, tasks: str | Path | None = None, on_step: Callable[[str], None] | None = None) -> NoiseSweep:
    """Run (or resume) the sweep into `out` and write its report (see the module doc)."""
    t_start, c_start = time.perf_counter(), _cpu_seconds()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    options = {"participants": sorted(participants), "seed": seed, "delta": delta, "kinds": list(kinds), "limit": limit,
               "annotations": str(annotations) if annotations else None, "repairs": repairs,
               "tasks": str(tasks) if tasks else None}
    meta_path = out / "noise.json"
    if meta_path.exists():
        old = json.loads(meta_path.read_text())
        if {k: old.get(k) for k in options} != options:
            raise MemoraError(f"{out}: holds a noise sweep with other options ({ {k: old.get(k) for k in options} }); "
                              "use another OUT")
        rates = sorted(set(rates) | set(old.get("rates", [])))
        errors = list(dict.fromkeys([*old.get("errors", []), *errors]))
    meta_path.write_text(json.dumps({**options, "rates": rates, "errors": errors}, indent=1) + "\n")
    from memora_graph.paths import epic_dir

    meta = Path(annotations).parent if annotations else epic_dir()
    df = load_annotations(annotations, participants=participants)
    if df.is_empty():
        raise MemoraError(f"no actions for participant(s) {', '.join(participants)}")
    classes = load_class_tables(meta)
    durations = dict(load_video_info(meta).select("video_id", "duration").iter_rows())
    families = verb_families(meta)
    sweep = NoiseSweep(out)
    cells = list(dict.fromkeys(("clean" if r == 0 else e, r) for r in coarse_first(rates) for e in errors))
    specs = []
    for error, rate in cells:  # the noisy annotations first (seconds), then the cells' work
        name = cell_name(error, rate)
        spec = NoiseSpec.of(MIXED if error == "clean" else error, rate, delta=delta, seed=seed)
        folder = out / "cells" / name / "annotations"
        if not (folder / "noise.json").exists():
            if on_step:
                on_step(f"{name}: injecting errors")
            write_noisy(folder, inject_noise(df, classes, spec, durations, families), meta, spec,
                        source=str(annotations or "bundled annotations"))
        specs.append(dict(cell=str(out / "cells" / name), name=name, error=error, rate=rate))
    common = dict(participants=participants, conditions=conditions, kinds=kinds, limit=limit, tasks=tasks, repairs=repairs)
    jobs = max(1, min(jobs if jobs is not None else auto_cell_jobs(len(specs)), len(specs)))
    if jobs == 1:
        for s in specs:
            sweep.cells.append(_run_cell(**s, **common, workers=workers, on_step=on_step))
    else:
        sweep.cells = _run_cells_parallel(specs, common, jobs, on_step)
    sweep.jobs = jobs
    sweep.seconds = time.perf_counter() - t_start
    sweep.cpu_seconds = _cpu_seconds() - c_start
    write_noise_report(out)
    timing = out / "timing.json"
    old = json.loads(timing.read_text()) if timing.exists() else []
    session = {"seconds": round(sweep.seconds, 1), "cpu_seconds": round(sweep.cpu_seconds, 1), "jobs": sweep.jobs,
               "load_at_end": [round(x, 2) for x in os.getloadavg()], "cells": sweep.cells}
    timing.write_text(json.dumps([*old, session], indent=1) + "\n")
    return sweep


def coarse_first(rates: list[float]) -> list[float]:
    """The order cells run in: rate 0, the middle rate, the highest, the lowest, then the rest
    (each for every error type in turn), so a sweep stopped early has a coarse curve in every panel."""
    rest = [r for r in sorted(set(rates)) if r > 0]
    head = [0.0] if 0 in rates else []
    if not rest:
        return head
    first = list(dict.fromkeys([rest[(len(rest) - 1) // 2], rest[-1], rest[0]]))
    return head + first + [r for r in rest if r not in first]


def auto_cell_jobs(n_cells: int) -> int:
    """Cells side by side: one process per core (each builds and reads its cells in-process)."""
    return max(1, min(n_cells, os.cpu_count() or 1))


def _cpu_seconds() -> float:
    """CPU-seconds of this process and of its finished children (user + system)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _run_cell(cell: str, name: str, error: str, rate: float, *, participants: list[str], conditions, kinds, limit,
              tasks, repairs: bool, workers: int | None = None, on_step: Callable[[str], None] | None = None) -> dict:
    """Build a cell's three banks (skipping complete ones) from its noisy annotations, run (or
    resume) its evaluation and write its repair table, all in this process unless `workers` > 1
    (the embedding cache emptied before each build and the run: the records of fresh processes)."""
    from memora_graph.pipeline import build_bank
    from memora_graph.retrieve.view import persist_bank

    with same_batches() as texts:  # a list of texts embedded again (another bank's same segments) is not embedded twice
        t0, c0 = time.perf_counter(), _cpu_seconds()
        cell = Path(cell)
        folder = cell / "annotations"
        for kind, opts in BANKS.items():
            bank = cell / "banks" / kind
            if (bank / ".complete").exists():
                continue
            if on_step:
                on_step(f"{name}: building the {kind} bank")
            clear_embedding_caches()  # each bank as a fresh `memora build` makes it, vector for vector
            with _repairs_switch(repairs):
                build_bank(bank, participants, annotations=folder / "annotations.csv", jobs=1, **opts)
            (bank / ".complete").write_text("")
        for kind in TOOL_BANKS:
            # the tool stores `memora build` writes after its build (nothing to do when they are
            # fresh). Without them the run's first open of a bank writes them but returns a view on
            # Kùzu, which the run keeps: every segment a tool returns was then one Kùzu lookup
            # (`MemoryView.by_id`, ~88k a P01 cell pair, a third of its CPU), where a view on the
            # stores reads the rows kept with them. The records are the same either way.
            persist_bank(cell / "banks" / kind, participants)
        if on_step:
            on_step(f"{name}: running the evaluation")
        run = dict(participants=participants, tasks=tasks, raw_bank=cell / "banks" / "raw",
                   episodic_bank=cell / "banks" / "episodic", kinds=kinds, limit=limit)
        if workers is not None and workers > 1:
            run_bench(cell / "banks" / "edited", cell / "run", conditions=conditions, workers=workers, **run)
        else:
            # `bench run`'s own worker processes take the conditions in groups (`split_conditions`),
            # each group's embeddings made in a fresh process: here each group runs in turn from an
            # empty embedding cache, so its vectors and records are those groups' (tests check it)
            conds = resolve_conditions(conditions)
            for group in split_conditions(conds, resolve_workers(None, "offline", len(conds))):
                clear_embedding_caches()
                run_bench(cell / "banks" / "edited", cell / "run", conditions=[c.name for c in group], workers=1, **run)
        repair = repair_table(cell, participants)
        (cell / "repair.json").write_text(json.dumps(repair, indent=1) + "\n")
        done = {"cell": name, "error": error, "rate": rate, "seconds": round(time.perf_counter() - t0, 1),
                "cpu_seconds": round(_cpu_seconds() - c0, 1), "pid": os.getpid(),
                "texts_embedded": texts.embedded, "texts_spared": texts.spared,  # in this process (`same_batches`)
                "load_at_end": [round(x, 2) for x in os.getloadavg()]}
        with open(cell / "timing.jsonl", "a") as fh:  # one line per session that worked on the cell
            fh.write(json.dumps(done) + "\n")
        if on_step:
            on_step(f"{name}: done in {done['seconds']:.0f} s, {done['cpu_seconds']:.0f} CPU-s")
        return done


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _run_cells_parallel(specs: list[dict], common: dict, jobs: int, on_step: Callable[[str], None] | None) -> list[dict]:
    """The cells over `jobs` long-lived worker processes (spawned: no forked Kùzu or torch state),
    each running whole cells in-process with one reader (`workers=1`), its models loaded once. The
    clean cell goes first; records do not depend on `jobs`."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    done: list[dict] = []
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(_run_cell, **s, **common, workers=1, on_step=_say if on_step else None): s["name"]
                   for s in specs}
        for f in as_completed(futures):
            done.append(f.result())  # a failed cell raises here; finished cells are kept for a resume
    order = [s["name"] for s in specs]
    return sorted(done, key=lambda c: order.index(c["cell"]))


@contextmanager
def _repairs_switch(on: bool):
    """The editor's repair rules (form/repair.py) on or off for the builds in this process."""
    old = os.environ.get(REPAIRS_ENV)
    os.environ[REPAIRS_ENV] = "on" if on else "off"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(REPAIRS_ENV, None)
        else:
            os.environ[REPAIRS_ENV] = old


# -- the repair table ----------------------------------------------------------------------------


def _kind_of(entity_id: str) -> str:
    """An entity id's object id without its participant and duplicate suffix (P01:red_plate#2 -> red_plate)."""
    return entity_id.split(":", 1)[-1].split("#")[0].split("@")[0]


def _is_kind(entity_id: str, kind: str) -> bool:
    obj = _kind_of(entity_id)
    return obj == kind or obj.endswith("_" + kind)


def repair_table(cell: Path, participants: list[str]) -> dict[str, dict[str, int]]:
    """Per error type, what the online editor (the edited bank) did with each injected error:

    - alias, swap: `undone` when the mistaken mention landed on an entity of the true object's kind
      (merged back); `worse` when it updated an object of another kind that memory already held
      (the error now corrupts a real object's state and place; the raw bank keeps it apart);
      `kept` otherwise (a record under the wrong name, as in the raw bank);
    - state: `undone` when the object's history holds the missed state at or after the error,
      restored by the editor (an event marked restored); `kept` otherwise;
    - drop, segment, verb, time: nothing observed to repair (or nothing the editor reads:
      verbs and times are the perceiver's); counted as `kept`.
    """
    errors = read_errors(cell / "annotations")
    bank = Bank(cell / "banks" / "edited")
    events: dict[tuple[str, str], list[dict]] = {}  # (participant, video) -> observations
    for p in participants:
        with bank.open(p) as store:
            for r in store.rows("_baseline_state_events_all", participant=p):
                events.setdefault((p, r["video"]), []).append(r)
    out = {t: {"injected": 0, "undone": 0, "worse": 0, "kept": 0} for t in ERROR_TYPES}
    for e in errors:
        row = out[e["type"]]
        row["injected"] += 1
        obs = events.get((e["participant"], e["video"]), [])
        t = e.get("t_out", e["t"])
        here = [o for o in obs if abs(float(o["t"]) - t) < 0.006]
        verdict = "kept"
        if e["type"] in ("alias", "swap"):
            true_kind = slug(noun_phrase(e["before"]))
            wrong_kind = slug(noun_phrase(e["after"]))
            mine = [o for o in here if _is_kind(o["entity"], true_kind) or _is_kind(o["entity"], wrong_kind)
                    or "repair" in (o.get("narration") or "")]
            if any(_is_kind(o["entity"], true_kind) for o in mine):
                verdict = "undone"
            elif any(_is_kind(o["entity"], wrong_kind) and o["op"] in ("UPDATE", "NOOP") for o in mine):
                verdict = "worse"
        elif e["type"] == "state":
            want = VERB_STATE.get(e.get("verb", ""), "")
            later = [o for o in obs if float(o["t"]) >= t - 0.006 and o["state"] == want
                     and "restored" in (o.get("narration") or "")]
            if later:
                verdict = "undone"
        row[verdict] += 1
    return out


# -- curves and the report -------------------------------------------------------------------------


def _cell_rows(out: Path) -> list[dict]:
    meta = json.loads((out / "noise.json").read_text())
    rows = []
    for error in meta["errors"]:
        for rate in meta["rates"]:
            name = cell_name(error, rate)
            run = out / "cells" / name / "run"
            if not (out / "cells" / name / "repair.json").exists():
                continue  # not finished yet (a cell writes its repair table after its run): partial records would mislead
            data = load_run(run)
            for cond in sorted(set(data["eam_qa"]) | set(data["planning"])):
                eam = eam_scores(data["eam_qa"].get(cond, [])) if data["eam_qa"].get(cond) else None
                rgp = {}
                for split in ("replay", "generalize"):
                    scores = [r["scores"] for r in data["planning"].get(cond, []) if r.get("split") == split
                              and r.get("scores")]
                    rgp[split] = planning_panel(scores)["rgp"] if scores else None
                defined = [v for v in rgp.values() if v is not None]
                rows.append({"error": error, "rate": rate, "cell": name, "condition": cond,
                             "accuracy": None if eam is None or eam["accuracy"] is None else round(100 * eam["accuracy"], 2),
                             "n_questions": eam["n"] if eam else 0, "rgp_replay": rgp["replay"],
                             "rgp_generalize": rgp["generalize"], "rgp": round(mean(defined), 4) if defined else None})
    return rows


def break_even(rows: list[dict], error: str) -> dict[str, Any]:
    """Where MEMORA's accuracy falls to the best baseline's clean accuracy: the rate found by
    linear interpolation between the measured rates (None: not reached within them)."""
    clean = {r["condition"]: r["accuracy"] for r in rows if r["rate"] == 0 and r["accuracy"] is not None}
    base = [(clean[b], b) for b in BASELINES if b in clean]
    if MEMORA not in clean or not base:
        return {"rate": None, "baseline": None, "baseline_clean": None, "note": "needs the clean cell with MEMORA and a baseline"}
    line, best = max(base)
    curve = sorted((r["rate"], r["accuracy"]) for r in rows if r["condition"] == MEMORA and r["error"] == error
                   and r["accuracy"] is not None)
    curve = [(0.0, clean[MEMORA])] + [c for c in curve if c[0] > 0]
    out = {"baseline": best, "baseline_clean": line, "memora_clean": clean[MEMORA]}
    if clean[MEMORA] <= line:
        return {**out, "rate": 0.0, "note": "MEMORA is not above the best baseline on clean input"}
    for (r0, a0), (r1, a1) in zip(curve, curve[1:]):
        if a1 <= line:
            rate = r0 + (r1 - r0) * (a0 - line) / (a0 - a1) if a0 != a1 else r1
            return {**out, "rate": round(rate, 3), "note": f"between {r0:g} and {r1:g}"}
    top = curve[-1][0] if curve else 0
    return {**out, "rate": None, "note": f"not reached up to rate {top:g}"}


def write_noise_report(out: str | Path) -> dict[str, Path]:
    """curves.parquet, repair.parquet, figures/, report.md and report.json of a sweep directory."""
    out = Path(out)
    if not (out / "noise.json").exists():
        raise MemoraError(f"{out}: not a noise sweep (no noise.json; `memora bench noise OUT` writes one)")
    meta = json.loads((out / "noise.json").read_text())
    rows = _cell_rows(out)
    if not rows:
        raise MemoraError(f"{out}: no finished cell yet")
    pl.DataFrame(rows, infer_schema_length=None).write_parquet(out / "curves.parquet")
    repair_rows = []
    for error in meta["errors"]:
        for rate in meta["rates"]:
            path = out / "cells" / cell_name(error, rate) / "repair.json"
            if path.exists() and rate > 0:
                for t, v in json.loads(path.read_text()).items():
                    if v["injected"]:
                        repair_rows.append({"error": error, "rate": rate, "type": t, **v})
    if repair_rows:
        pl.DataFrame(repair_rows).write_parquet(out / "repair.parquet")
    errors = [e for e in meta["errors"]]
    report: dict[str, Any] = {"options": meta, "break_even": {e: break_even(rows, e) for e in errors},
                              "processed_vs_raw": {}, "curves": rows, "repair": repair_rows}
    for e in errors:
        per_rate = {}
        for rate in meta["rates"]:
            acc = {r["condition"]: r["accuracy"] for r in rows if r["rate"] == rate and (r["error"] == e or rate == 0)}
            per_rate[f"{rate:g}"] = {
                f"{kind}_pp": (None if acc.get(f"{kind}_edited") is None or acc.get(f"{kind}_raw") is None
                               else round(acc[f"{kind}_edited"] - acc[f"{kind}_raw"], 2)) for kind in ("flat_1d", "graph_2d")}
        report["processed_vs_raw"][e] = per_rate
    figures = _figures(out, rows, errors, meta["rates"])
    (out / "report.json").write_text(json.dumps(report, indent=1, default=str) + "\n")
    md = _markdown(report, figures, out)
    (out / "report.md").write_text(md)
    return {"markdown": out / "report.md", "json": out / "report.json", "curves": out / "curves.parquet",
            **{f.stem: f for f in figures}}


def _figures(out: Path, rows: list[dict], errors: list[str], rates: list[float]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = out / "figures"
    folder.mkdir(exist_ok=True)
    paths = []
    conds = sorted({r["condition"] for r in rows})
    for metric, label in (("accuracy", "EAM-QA accuracy (%)"), ("rgp", "RGP")):
        fig, axes = plt.subplots(1, len(errors), figsize=(4 * len(errors), 3.6), sharey=True, squeeze=False)
        for ax, e in zip(axes[0], errors):
            for c in conds:
                pts = sorted((r["rate"], r[metric]) for r in rows if r["condition"] == c and (r["error"] == e or r["rate"] == 0)
                             and r[metric] is not None)
                if pts:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=c,
                            linewidth=2.2 if c == MEMORA else 1.2, linestyle="--" if c.endswith("_raw") else "-")
            ax.set_title(e)
            ax.set_xlabel("error rate")
            ax.set_xticks(rates)
            ax.grid(alpha=0.3)
        axes[0][0].set_ylabel(label)
        axes[0][-1].legend(fontsize=7, loc="best")
        fig.tight_layout()
        path = folder / f"{metric}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def _markdown(report: dict, figures: list[Path], out: Path) -> str:
    meta = report["options"]
    lines = [f"# Memory under imperfect perception: {', '.join(meta['participants'])}", "",
             f"Rates {', '.join(f'{r:g}' for r in meta['rates'])}; errors {', '.join(meta['errors'])}; seed {meta['seed']}; "
             f"time shift up to +-{meta['delta']:g} s; editor repair rules {'on' if meta.get('repairs') else 'off'}. Every cell's run is a `bench run` directory "
             f"(`memora bench compare {out}/cells/A/run {out}/cells/B/run`).", ""]
    for f in figures:
        lines.append(f"![{f.stem}](figures/{f.name})")
    lines += ["", "## Break-even rate (MEMORA's accuracy falls to the best baseline's clean accuracy)", "",
              "| error | break-even rate | best baseline (clean) | MEMORA clean | note |", "|---|---|---|---|---|"]
    for e, b in report["break_even"].items():
        rate = "-" if b["rate"] is None else f"{b['rate']:g}"
        lines.append(f"| {e} | {rate} | {b.get('baseline')} ({b.get('baseline_clean')}) | {b.get('memora_clean')} | {b['note']} |")
    lines += ["", "## EAM-QA accuracy (%) per condition", ""]
    rows = report["curves"]
    conds = sorted({r["condition"] for r in rows})
    for e in report["break_even"]:
        lines += [f"### {e}", "", "| rate | " + " | ".join(conds) + " |", "|---" * (len(conds) + 1) + "|"]
        for rate in meta["rates"]:
            acc = {r["condition"]: r for r in rows if r["rate"] == rate and (r["error"] == e or rate == 0)}
            if acc:
                lines.append(f"| {rate:g} | " + " | ".join(
                    "-" if c not in acc or acc[c]["accuracy"] is None else
                    f"{acc[c]['accuracy']:.1f}" + ("" if acc[c]["rgp"] is None else f" / {acc[c]['rgp']:.3f}")
                    for c in conds) + " |")
        lines.append("")
    lines += ["(each cell: accuracy / RGP)", "", "## Processed minus raw (EAM-QA points)", "",
              "| error | rate | Flat-1D | Graph-2D |", "|---|---|---|---|"]
    for e, per in report["processed_vs_raw"].items():
        for rate, v in per.items():
            if v["flat_1d_pp"] is not None or v["graph_2d_pp"] is not None:
                lines.append(f"| {e} | {rate} | {v['flat_1d_pp']} | {v['graph_2d_pp']} |")
    lines += ["", "## The editor's repair table (edited bank; see bench/noise.py `repair_table`)", "",
              "| error | rate | type | injected | undone | made worse | kept |", "|---|---|---|---|---|---|---|"]
    for r in report["repair"]:
        lines.append(f"| {r['error']} | {r['rate']:g} | {r['type']} | {r['injected']} | {r['undone']} | {r['worse']} | {r['kept']} |")
    return "\n".join(lines) + "\n"


def remove_cell(out: str | Path, name: str) -> None:
    """Forget one cell (its annotations, banks and run), so the next sweep makes it again."""
    shutil.rmtree(Path(out) / "cells" / name, ignore_errors=True)


__all__ = ["NoiseSweep", "break_even", "parse_errors", "parse_rates", "repair_table", "run_noise", "write_noise_report"]

"""The report of a run directory: pure aggregation of the per-item records (bench.metrics), written
as report.json, report.md and report.html. Every number can be traced to the records it came from.

Tables: EAM-QA accuracy / E-selection / per-type accuracy per condition; the three evaluation views
(full; MEMORA-committed; parametric-missed + MEMORA-committed), pooled and macro over participants;
MEMORA against the best baseline per type and the consolidation lift (MEMORA - MEMORA-Episodic) per
type; the planning panel per condition and split (OrderExec, KeyObj, PrefAdh, RGP, Exec, KBGround,
ObjGT-F1, GF1); tool calls per condition, per tool and per store; memory formation (compression,
decision mix); latency (model / tools / other).
Figures (matplotlib, PNG next to the report): RGP per condition and split with MEMORA's change
against the best baseline; the compression curve; the editor's decision mix.
"""

from __future__ import annotations

import json
import re
import textwrap
from collections import Counter, defaultdict
from pathlib import Path
from statistics import mean, median
from typing import Any

from memora_graph.bench.conditions import get_condition, list_conditions
from memora_graph.bench.aggregate import eam_scores, eam_views, planning_panel
from memora_graph.bench.run import load_run, write_results_table
from memora_graph.bench.tasks import QA_TYPES
from memora_graph.errors import MemoraError
from memora_graph.retrieve.registry import store_of
from memora_graph.text import counted

MEMORA, EPISODIC, PARAMETRIC = "memora_full", "memora_episodic", "no_memory"
BASELINES = ("flat_1d_raw", "flat_1d_edited", "graph_2d_raw", "graph_2d_edited")
PANEL = ("order_exec", "key_obj", "pref_adh", "rgp", "exec", "kb_ground", "objgt_f1", "gf1")
PANEL_LABELS = {"order_exec": "OrderExec", "key_obj": "KeyObj", "pref_adh": "PrefAdh", "rgp": "RGP", "exec": "Exec",
                "kb_ground": "KBGround", "objgt_f1": "ObjGT-F1", "gf1": "GF1"}


def _order(conds) -> list[str]:
    known = list_conditions()
    return sorted(conds, key=lambda c: (known.index(c) if c in known else 99, c))


def _label(c: str) -> str:
    try:
        return get_condition(c).label
    except MemoraError:
        return c


def _description(c: str) -> str:
    try:
        return get_condition(c).description
    except MemoraError:
        return ""


def _type_acc(records: list[dict], ids: set[str] | None = None) -> dict[str, float | None]:
    out = {}
    for t in QA_TYPES:
        rs = [r for r in records if r["qa_type"] == t and (ids is None or r["question_id"] in ids)]
        out[t] = sum(r["predicted"] == r["correct_answer"] for r in rs) / len(rs) if rs else None
    return out


def build_report(run: str | Path) -> dict[str, Any]:
    data = load_run(run)
    manifest_path = Path(run) / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
    out: dict[str, Any] = {"run": str(run), "manifest": manifest, "eam_qa": {}, "planning": {}}
    eam = data["eam_qa"]
    conds = _order(eam)
    if conds:
        out["eam_qa"]["conditions"] = {c: {**eam_scores(eam[c]), "label": _label(c),
                                           "n_failed_items": sum(r["status"] != "ok" for r in eam[c])} for c in conds}
        by_p = {c: _by_participant(eam[c]) for c in conds}
        if MEMORA in by_p:
            views = eam_views(by_p, memora=MEMORA, parametric=PARAMETRIC,
                              baselines=[b for b in BASELINES if b in by_p])
            out["eam_qa"]["views"] = views
            headline = _headline_ids(by_p)
            out["eam_qa"]["per_type_views"] = {
                "full": {c: _type_acc(eam[c]) for c in conds},
                "parametric_missed_memora_committed": {c: _type_acc(eam[c], headline) for c in conds} if headline is not None else None,
            }
            out["eam_qa"]["memora_vs_best_baseline"] = _vs_best(out["eam_qa"]["per_type_views"], conds)
            if EPISODIC in by_p:
                out["eam_qa"]["consolidation_lift_pp"] = {
                    view: {t: (None if vals is None or vals[MEMORA][t] is None or vals[EPISODIC][t] is None
                               else round(100 * (vals[MEMORA][t] - vals[EPISODIC][t]), 1)) for t in QA_TYPES}
                    for view, vals in out["eam_qa"]["per_type_views"].items()}
        else:
            out["eam_qa"]["views"] = None
            out["eam_qa"]["note"] = "the three views need the memora_full condition in the run"
    if conds:
        out["eam_qa"]["abstention"] = {c: _abstention(eam[c]) for c in conds}
        cal = _calibration_section(eam, conds)
        if cal:
            out["eam_qa"]["calibration"] = cal
    plan = data["planning"]
    for c in _order(plan):
        per_split = {}
        for split in ("replay", "generalize"):
            scores = [r["scores"] for r in plan[c] if r.get("split") == split and r.get("scores")]
            if scores:
                per_split[split] = planning_panel(scores)
        out["planning"][c] = {"label": _label(c), **per_split,
                              "n_failed_items": sum(r["status"] != "ok" for r in plan[c])}
    if plan:
        out["planning_vs_best_baseline"] = _plan_vs_best(out["planning"])
    all_recs = [(c, r) for kind in data.values() for c, rs in kind.items() for r in rs]
    tools: dict[str, Counter] = defaultdict(Counter)
    for c, r in all_recs:
        for call in r.get("tool_calls") or []:
            tools[c][call["name"]] += 1
            tools[c]["_duplicate"] += bool(call.get("duplicate"))
    out["tool_calls"] = {c: dict(sorted(tools[c].items())) for c in _order(tools)}
    out["tool_calls_per_store"] = _per_store(out["tool_calls"])
    out["memory_formation"] = _formation(Path(run))
    lat: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for c, r in all_recs:
        for k, v in (r.get("time") or {}).items():
            lat[c][k].append(v)
    out["latency_s"] = {c: {k: round(mean(v), 4) for k, v in lat[c].items()} | {"items": len(lat[c]["total_s"])}
                        for c in _order(lat)}
    return out


def _abstention(records: list[dict]) -> dict[str, Any]:
    """How often E is answered where it is wrong (answerable questions) and where it is right
    (the E-correct controls), and why the reader abstained on answerable ones."""
    ans = [r for r in records if r["correct_answer"] != "E"]
    ctl = [r for r in records if r["correct_answer"] == "E"]
    reasons: Counter = Counter()
    for r in ans:
        if r.get("predicted") == "E":
            m = re.search(r"; (no record of the [a-z ]+|the evidence[^;(\n]*)", r.get("final_text") or "")
            reasons[m.group(1).strip() if m else "other"] += 1
    return {"answerable_n": len(ans), "controls_n": len(ctl),
            "answerable_abstained": sum(r.get("predicted") == "E" for r in ans) / len(ans) if ans else None,
            "controls_answered_e": sum(r.get("predicted") == "E" for r in ctl) / len(ctl) if ctl else None,
            "abstain_reasons": dict(reasons.most_common())}


def _calibration_section(eam: dict[str, list[dict]], conds: list[str]) -> dict[str, Any] | None:
    """Per condition whose records carry a confidence: ECE, reliability bins, coverage accuracy,
    over the participants the installed calibration was fitted on and over the others (held out)."""
    from memora_graph.agent.confidence import load_calibration
    from memora_graph.bench.calibration import calibration_summary

    cal = load_calibration()
    fitted = set((cal.fitted_on.get("participants") or []) if cal else [])
    out: dict[str, Any] = {"fitted_on": sorted(fitted), "conditions": {}}
    for c in conds:
        groups = {"all": eam[c]}
        if fitted:
            groups["fitted"] = [r for r in eam[c] if r["participant"] in fitted]
            groups["held_out"] = [r for r in eam[c] if r["participant"] not in fitted]
        per = {g: calibration_summary(rs) for g, rs in groups.items()}
        if per["all"] is not None:
            out["conditions"][c] = per
    return out if out["conditions"] else None


# the store each tool reads (the paper's per-store tool-use figure) comes from its ToolSpec: a
# baseline's tools read its one representation, MEMORA's `search` fans out over every store
CURVE_SEGMENTS = 150  # compression.png draws the first segments only (the curves part early; the rest is straight)
STORES = ("Entity", "Activity", "Environment", "Inferred", "unified search", "Flat-1D records", "Graph-2D graph")


def _store_of(condition: str, tool: str) -> str:
    try:
        family = get_condition(condition).memory
    except MemoraError:
        family = None
    return store_of(tool, family) if family else tool


def _per_store(tool_calls: dict[str, dict[str, int]]) -> dict[str, dict[str, Any]]:
    """Calls per condition and store, with each store's share of the condition's calls."""
    out = {}
    for c, counts in tool_calls.items():
        per: Counter = Counter()
        for tool, n in counts.items():
            if not tool.startswith("_"):
                per[_store_of(c, tool)] += n
        total = sum(per.values())
        out[c] = {"total": total, "calls": dict(per),
                  "share": {k: round(v / total, 4) for k, v in per.items()} if total else {}}
    return out


def _formation(run: Path) -> dict[str, Any] | None:
    """The memory-formation data the run saved per participant (bench run writes it)."""
    folder = run / "memory_formation"
    files = sorted(folder.glob("*.json")) if folder.is_dir() else []
    if not files:
        return None
    per = {f.stem: json.loads(f.read_text()) for f in files}
    decisions: Counter = Counter()
    for v in per.values():
        decisions.update(v["decisions"])
    total = sum(decisions.values())
    ratios = [v["compression"] for v in per.values() if v["compression"]]
    return {
        "participants": per, "decisions": dict(decisions),
        "decision_share": {k: round(n / total, 4) for k, n in decisions.items()} if total else {},
        "compression": {p: v["compression"] for p, v in per.items()},
        "median_compression": round(median(ratios), 2) if ratios else None,
    }


def _by_participant(records: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = defaultdict(list)
    for r in records:
        out[r["participant"]].append(r)
    return dict(out)


def _headline_ids(by_p: dict[str, dict[str, list[dict]]]) -> set[str] | None:
    """Question ids where Parametric is wrong and MEMORA chose A-D (answered by every condition)."""
    if PARAMETRIC not in by_p:
        return None
    idx = {c: {r["question_id"]: r for rs in by_p[c].values() for r in rs} for c in by_p}
    common = set.intersection(*(set(v) for v in idx.values()))
    return {q for q in common if idx[MEMORA][q]["predicted"] in ("A", "B", "C", "D")
            and idx[PARAMETRIC][q]["predicted"] != idx[PARAMETRIC][q]["correct_answer"]}


def _vs_best(per_type_views: dict, conds: list[str]) -> dict:
    out = {}
    for view, vals in per_type_views.items():
        if vals is None:
            continue
        rows = {}
        for t in QA_TYPES:
            base = [(vals[b][t], b) for b in BASELINES if b in vals and vals[b][t] is not None]
            best = max(base) if base else (None, None)
            mem = vals[MEMORA][t]
            rows[t] = {"memora": mem, "best_baseline": best[1], "best_baseline_acc": best[0],
                       "delta_pp": None if mem is None or best[0] is None else round(100 * (mem - best[0]), 1)}
        out[view] = rows
    return out


def _plan_vs_best(planning: dict) -> dict:
    out = {}
    for split in ("replay", "generalize"):
        base = [(planning[b][split]["rgp"], b) for b in BASELINES
                if b in planning and split in planning[b] and planning[b][split]["rgp"] is not None]
        best = max(base) if base else (None, None)
        mem = planning.get(MEMORA, {}).get(split, {}).get("rgp")
        out[split] = {"memora_rgp": mem, "best_baseline": best[1], "best_baseline_rgp": best[0],
                      "delta": None if mem is None or best[0] is None else round(mem - best[0], 4)}
    return out


# -- rendering --------------------------------------------------------------------------------------


# What the report's names and columns mean, printed with every report (the reader of a report looks
# there, not in the repository's docs; docs/evaluation.md says the same at more length).
LEGEND = [
    ("Condition", "the memory the questions and tasks were answered with; the label is the paper's name, the name "
                  "in backticks is the one `--conditions` and the records use (`_edited` = built from the processed "
                  "bank, `_raw` = from the raw bank)"),
    ("n", "questions scored"),
    ("Acc %", "share of questions answered with the correct letter"),
    ("E-rate %", "share of questions answered E (\"not in memory\" / none of the options); the E-controls are "
                 "questions whose right answer is E"),
    ("SPref, SHabit, SRoutine, ERecall", "accuracy per question type: a stated preference, a habit (what follows an "
                                          "action), a routine (how a goal is done), recall of one named video"),
    ("failed", "questions whose run failed (scored as wrong)"),
    ("full", "every question all conditions answered"),
    ("memora_committed", "of those, the questions MEMORA answered with A-D (it committed to an option, not E)"),
    ("parametric_missed_memora_committed", "of those, the questions the Parametric condition (no memory) got wrong: "
                                           "what memory has to supply (the headline view)"),
    ("pooled (macro)", "pooled: right answers over all items of the view; macro, in parentheses: the mean of the "
                       "per-participant accuracies"),
    ("MEMORA - best baseline (pp)", "MEMORA's accuracy minus the best Flat-1D / Graph-2D condition's, in "
                                    "percentage points"),
    ("Consolidation lift (pp)", "MEMORA minus MEMORA-Episodic (the same typed stores without routines and "
                                "preferences)"),
    ("plans, empty", "plans scored, and empty plans (excluded from the means)"),
    ("OrderExec", "order of the plan's actions against the reference's: longest common subsequence of verbs / "
                  "reference verbs"),
    ("KeyObj", "share of the reference's key objects the plan mentions"),
    ("PrefAdh", "how far the plan follows the participant's relevant preferences"),
    ("RGP", "routine-grounded planning score: the mean of OrderExec, KeyObj and PrefAdh (those defined)"),
    ("Exec", "share of steps with an action, an object and a location"),
    ("KBGround", "share of the plan's objects that exist in the memory"),
    ("ObjGT-F1, GF1", "F1 of the plan's objects against the reference's; GF1 counts only objects the memory also has"),
    ("repeated", "tool calls that repeat an earlier call of the same item with the same arguments"),
    ("Compression", "object observations per live entity after the editor (raw memory: one record per observation)"),
]


def _legend() -> str:
    return _table(["Column", "Meaning"], [[f"`{k}`" if "_" in k else k, v] for k, v in LEGEND], text=True)


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f}"


def _num(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def _table(header: list[str], rows: list[list[str]], text: bool = False) -> str:
    """A markdown table; `text`: every column is words, aligned left (numbers are aligned right)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(":---" if text else "---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(x) for x in r) + " |" for r in rows]
    return "\n".join(lines)


def render_markdown(rep: dict[str, Any]) -> str:
    m = rep["manifest"]
    parts = [f"# MEMORA-Bench report: `{rep['run']}`", "",
             f"Backend: **{m.get('backend')}** ({m.get('model')}); participants: {', '.join(m.get('participants', []))}; "
             f"tasks: {m.get('tasks')} (hash {m.get('task_set_hash')}); code {m.get('code_version')}; "
             f"prompts {m.get('prompt_version')}."]
    if m.get("backend") == "offline":
        parts.append("\n> The `offline` backend is a deterministic retrieval-and-scoring policy, **not an LLM**: "
                     "these numbers measure the memories through a fixed simple reader.")
    conds = _order({c for key in ("planning", "tool_calls", "latency_s") for c in rep.get(key) or {}}
                   | set((rep.get("eam_qa") or {}).get("conditions") or {}))
    if conds:
        parts += ["", "## Conditions", "",
                  "Tables name conditions by their label; runs, records and `--conditions` by their name. "
                  "What each column means: *Reading this report*, at the end.", ""]
        parts.append(_table(["Condition", "name", "memory"], [[_label(c), f"`{c}`", _description(c)] for c in conds],
                            text=True))
    eam = rep.get("eam_qa") or {}
    if eam.get("conditions"):
        parts += ["", "## EAM-QA: full benchmark", ""]
        rows = []
        for c, s in eam["conditions"].items():
            rows.append([s["label"], s["n"], _pct(s["accuracy"]), _pct(s["e_rate"]),
                         *[_pct(s["per_type_accuracy"].get(t)) for t in QA_TYPES], s["n_failed_items"]])
        parts.append(_table(["Condition", "n", "Acc %", "E-rate %", *QA_TYPES, "failed"], rows))
        if eam.get("views"):
            parts += ["", "## EAM-QA: evaluation views (pooled accuracy %, macro in parentheses)", ""]
            views = eam["views"]
            names = [v for v in ("full", "memora_committed", "parametric_missed_memora_committed") if v in views]
            rows = []
            for c in eam["conditions"]:
                rows.append([_label(c)] + [
                    f"{_pct(views[v]['conditions'][c]['pooled'])} ({_pct(views[v]['conditions'][c]['macro'])})"
                    for v in names])
            rows.append(["n (items)"] + [str(views[v]["conditions"][MEMORA]["n"]) for v in names])
            rows.append(["MEMORA - best baseline (pp)"] + [
                f"{views[v]['delta_pp']:+.1f} vs {_label(views[v]['best_baseline'])}" if views[v]["delta_pp"] is not None
                else "-" for v in names])
            parts.append(_table(["Condition", *names], rows))
            if views.get("commit_rate") is not None:
                parts.append(f"\nMEMORA commit rate P(A-D | parametric wrong): {_pct(views['commit_rate'])}%.")
        for view, label in (("parametric_missed_memora_committed", "headline view"), ("full", "full benchmark")):
            vals = (eam.get("per_type_views") or {}).get(view)
            if vals:
                parts += ["", f"## EAM-QA per type, {label} (accuracy %)", ""]
                parts.append(_table(["Condition", *QA_TYPES],
                                    [[_label(c), *[_pct(vals[c][t]) for t in QA_TYPES]] for c in vals]))
                vs = (eam.get("memora_vs_best_baseline") or {}).get(view)
                if vs:
                    parts.append("\n" + _table(["", *QA_TYPES], [
                        ["MEMORA - best baseline (pp)", *[f"{vs[t]['delta_pp']:+.1f} ({_label(vs[t]['best_baseline'])})"
                                                          if vs[t]["delta_pp"] is not None else "-" for t in QA_TYPES]],
                        ["Consolidation lift (pp)", *[
                            f"{(eam.get('consolidation_lift_pp') or {}).get(view, {}).get(t):+.1f}"
                            if (eam.get('consolidation_lift_pp') or {}).get(view, {}).get(t) is not None else "-"
                            for t in QA_TYPES]]]))
    if eam.get("abstention"):
        parts += ["", "## EAM-QA: abstention (E answers)", ""]
        parts.append(_table(["Condition", "answerable abstained %", "E-controls answered E %", "reasons (answerable)"], [
            [_label(c), _pct(a["answerable_abstained"]), _pct(a["controls_answered_e"]),
             "; ".join(f"{k}: {v}" for k, v in a["abstain_reasons"].items()) or "-"]
            for c, a in eam["abstention"].items()]))
    if eam.get("calibration"):
        cal = eam["calibration"]
        parts += ["", "## EAM-QA: confidence (probability the answer is right)", ""]
        if cal["fitted_on"]:
            parts.append(f"Calibration fitted on {', '.join(cal['fitted_on'])}; \"held out\" is every other participant. "
                         "ECE: expected calibration error over ten equal-width bins. Accuracy at a coverage: over the "
                         "most confident answers only.\n")
        rows = []
        for c, per in cal["conditions"].items():
            for g, sm in per.items():
                if sm is None:
                    continue
                cov = sm["coverage_accuracy"]
                rows.append([_label(c), g.replace("_", " "), sm["n"], f"{sm['ece']:.3f}", _pct(sm["mean_confidence"]),
                             _pct(cov.get("100")), _pct(cov.get("80")), _pct(cov.get("50"))])
        parts.append(_table(["Condition", "participants", "n", "ECE", "mean confidence %", "acc % (100% coverage)",
                             "acc % (80%)", "acc % (50%)"], rows))
    if rep.get("planning"):
        for split in ("replay", "generalize"):
            rows = []
            for c, p in rep["planning"].items():
                if split in p:
                    s = p[split]
                    rows.append([p["label"], s["n_plans_scored"], s["n_empty_plans"], *[_num(s.get(a)) for a in PANEL]])
            if rows:
                parts += ["", f"## Planning: {split.capitalize()}", ""]
                parts.append(_table(["Condition", "plans", "empty", *[PANEL_LABELS[a] for a in PANEL]], rows))
                vs = rep.get("planning_vs_best_baseline", {}).get(split) or {}
                if vs.get("delta") is not None:
                    parts.append(f"\nMEMORA RGP {vs['memora_rgp']:.3f} vs best baseline {_label(vs['best_baseline'])} "
                                 f"{vs['best_baseline_rgp']:.3f}: {vs['delta']:+.3f}.")
    if rep.get("tool_calls"):
        names = sorted({n for v in rep["tool_calls"].values() for n in v if not n.startswith("_")})
        parts += ["", "## Tool calls per condition", ""]
        parts.append(_table(["Condition", *names, "repeated"],
                            [[_label(c), *[v.get(n, 0) for n in names], v.get("_duplicate", 0)]
                             for c, v in rep["tool_calls"].items()]))
    if rep.get("tool_calls_per_store"):
        seen = {st for v in rep["tool_calls_per_store"].values() for st in v["calls"]}
        stores = [st for st in STORES if st in seen] + sorted(seen - set(STORES))  # a newly registered store too
        parts += ["", "## Tool calls per store (calls, share of the condition's calls)", ""]
        parts.append(_table(["Condition", "calls", *stores], [
            [_label(c), v["total"], *[f"{v['calls'].get(st, 0)} ({_pct(v['share'].get(st, 0.0))}%)" for st in stores]]
            for c, v in rep["tool_calls_per_store"].items()]))
    form = rep.get("memory_formation")
    if form:
        parts += ["", "## Memory formation (the MEMORA bank)", ""]
        parts.append(_table(["", *sorted(form["compression"]), "median"],
                            [["Compression (observations / live entities)",
                              *[f"{form['compression'][p]:.1f}x" if form["compression"][p] else "-"
                                for p in sorted(form["compression"])],
                              f"{form['median_compression']:.1f}x" if form["median_compression"] else "-"]]))
        ops = [o for o in ("NOOP", "UPDATE", "ADD", "DELETE") if o in form["decisions"]]
        parts.append("\n" + _table(["Editor decisions", *ops, "n"], [
            ["share %", *[_pct(form["decision_share"].get(o)) for o in ops], sum(form["decisions"].values())]]))
    if rep.get("figures"):
        parts += ["", "## Figures", ""] + [f"![{f}]({f})" for f in rep["figures"]]
    if rep.get("latency_s"):
        parts += ["", "## Latency per item (mean seconds)", ""]
        parts.append(_table(["Condition", "items", "model", "tools", "other", "total"],
                            [[_label(c), v.get("items", 0), _num(v.get("model_s")), _num(v.get("tools_s")),
                              _num(v.get("other_s")), _num(v.get("total_s"))] for c, v in rep["latency_s"].items()]))
    parts += ["", "## Reading this report", "", _legend(), ""]
    return "\n".join(parts)


def render_html(markdown: str) -> str:
    """The report's markdown as one HTML page (CommonMark with tables, by markdown-it-py)."""
    from markdown_it import MarkdownIt

    body = MarkdownIt("commonmark", {"html": False}).enable("table").render(markdown)
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse;margin:1em 0}"
             "td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}td:first-child,th:first-child{text-align:left}"
             "blockquote{margin:1em 0;padding:0 1em;border-left:3px solid #ccc}"
             # figures scale to the page: the RGP figure takes the row, the three small ones share the next
             "img{max-width:100%;height:auto;vertical-align:top}"
             "img[src='reliability.png'],img[src='compression.png'],img[src='decisions.png']{max-width:32%}")
    return f"<!doctype html><html><head><meta charset='utf-8'><style>{style}</style></head><body>{body}</body></html>"


def _figures(rep: dict[str, Any], out: Path) -> list[Path]:
    """rgp.png (RGP per condition and split, MEMORA's change against the best non-MEMORA
    baseline written over its bar), compression.png (cumulative Entity Memory records with and
    without the editor, median over participants), decisions.png (the editor's decision mix)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    plan = rep.get("planning") or {}
    splits = [sp for sp in ("replay", "generalize") if any(sp in p for p in plan.values())]
    if splits:
        fig, axes = plt.subplots(1, len(splits), figsize=(6 * len(splits), 3.6), squeeze=False)
        for ax, split in zip(axes[0], splits):
            rows = [(c, p["label"], p[split]["rgp"]) for c, p in plan.items()
                    if split in p and p[split]["rgp"] is not None]
            colors = ["tab:red" if c == MEMORA else "tab:orange" if c == EPISODIC else
                      "tab:gray" if c == PARAMETRIC else "tab:blue" for c, _, _ in rows]
            ax.bar(range(len(rows)), [r[2] for r in rows], color=colors)
            ax.set_xticks(range(len(rows)), [r[1] for r in rows], rotation=35, ha="right", fontsize=8)
            ax.set_ylabel("RGP")
            vs = (rep.get("planning_vs_best_baseline") or {}).get(split) or {}
            title = f"{split.capitalize()}"
            if vs.get("delta") is not None:
                i = [r[0] for r in rows].index(MEMORA)
                ax.annotate(f"{vs['delta']:+.3f} vs {_label(vs['best_baseline'])}", (i, rows[i][2]),
                            xytext=(0, 4), textcoords="offset points", ha="center", fontsize=8)
                ax.axhline(vs["best_baseline_rgp"], color="tab:blue", linestyle=":", linewidth=1)
            ax.set_title(title)
            ax.set_ylim(0, max([r[2] for r in rows] + [0.1]) * 1.2)
        fig.tight_layout()
        paths.append(_save(fig, out / "rgp.png", plt))
    cal = ((rep.get("eam_qa") or {}).get("calibration") or {}).get("conditions") or {}
    if MEMORA in cal:
        groups = [(g, sm) for g, sm in cal[MEMORA].items() if sm is not None and (g != "all" or len(cal[MEMORA]) == 1)]
        fig, ax = plt.subplots(figsize=(4.8, 4.2))
        ax.plot([0, 1], [0, 1], color="tab:gray", linestyle=":", linewidth=1, label="perfectly calibrated")
        for (g, sm), color in zip(groups, ("tab:blue", "tab:red", "tab:green")):
            bins = sm["reliability"]
            ax.plot([b["confidence"] for b in bins], [b["accuracy"] for b in bins], marker="o", color=color,
                    label=f"{g.replace('_', ' ')} (n={sm['n']}, ECE {sm['ece']:.3f})")
            for b in bins:
                ax.annotate(str(b["n"]), (b["confidence"], b["accuracy"]), xytext=(3, -9), textcoords="offset points",
                            fontsize=6, color=color)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.set_xlabel("confidence (P the answer is right)")
        ax.set_ylabel("accuracy")
        ax.set_title("MEMORA reliability diagram (10 bins; labels: items)", fontsize=9)
        ax.legend(fontsize=7, loc="upper left")
        fig.tight_layout()
        paths.append(_save(fig, out / "reliability.png", plt))
    form = rep.get("memory_formation")
    if form:
        import numpy as np

        per = list(form["participants"].values())
        n = min(CURVE_SEGMENTS, max(len(v["without_editor"]) for v in per))
        without = np.array([[v["without_editor"][min(i, len(v["without_editor"]) - 1)] for i in range(n)]
                            for v in per if v["without_editor"]])
        edited = np.array([[v["with_editor"][min(i, len(v["with_editor"]) - 1)] for i in range(n)]
                           for v in per if v["with_editor"]])
        fig, ax = plt.subplots(figsize=(5.5, 3.6))
        x = np.arange(1, n + 1)
        ax.plot(x, np.median(without, axis=0), label="without editor (one record per observation)")
        ax.plot(x, np.median(edited, axis=0), label="MEMORA editor (live entities)")
        words = compression_words(form, float(np.median(without[:, -1])), float(np.median(edited[:, -1])))
        ax.set_xlabel("\n".join(textwrap.wrap(words["xlabel"], 60)))  # wrapped: the figure is 5.5 in wide
        ax.set_ylabel("Entity Memory records (median)")
        ax.set_title("\n".join(textwrap.wrap(words["title"], 60)), fontsize=9)
        ax.legend(fontsize=8)
        fig.tight_layout()
        paths.append(_save(fig, out / "compression.png", plt))
        ops = [o for o in ("NOOP", "UPDATE", "ADD", "DELETE") if o in form["decisions"]]
        fig, ax = plt.subplots(figsize=(4.5, 3.2))
        shares = [100 * form["decision_share"][o] for o in ops]
        ax.bar(ops, shares, color=["tab:gray", "tab:blue", "tab:green", "tab:red"][:len(ops)])
        for i, v in enumerate(shares):
            ax.annotate(f"{v:.1f}%", (i, v), xytext=(0, 3), textcoords="offset points", ha="center", fontsize=8)
        ax.set_ylabel("% of object observations")
        ax.set_title(f"Editor decisions (n={sum(form['decisions'].values()):,})", fontsize=9)
        fig.tight_layout()
        paths.append(_save(fig, out / "decisions.png", plt))
    return paths


def compression_words(form: dict[str, Any], without_at_cut: float, edited_at_cut: float) -> dict[str, str]:
    """compression.png's axis label and title. The curve shows the first CURVE_SEGMENTS segments; when the
    memories are longer both say so, with the compression where the curve stops next to the whole memory's."""
    per = list(form["participants"].values())
    longest = max(len(v["without_editor"]) for v in per)
    n = min(CURVE_SEGMENTS, longest)
    whole = f"{form['median_compression']:.1f}x" if form["median_compression"] else "-"
    if n < longest:
        return {"xlabel": f"the first {n} of up to {longest:,} segments with object observations (10 s each)",
                "title": f"Cumulative records, {counted(len(per), 'participant')}: {without_at_cut / max(edited_at_cut, 1):.1f}x "
                         f"at segment {n}, {whole} over the whole memory (median)"}
    return {"xlabel": "segments with object observations (10 s each)",
            "title": f"Cumulative records, {counted(len(per), 'participant')}; median compression {whole}"}


def _save(fig, path: Path, plt) -> Path:
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def write_report(run: str | Path) -> dict[str, Path]:
    run = Path(run)
    if not (run / "records").is_dir():
        raise MemoraError(f"{run}: not a run directory (no records/); create one with `memora bench run`")
    rep = build_report(run)
    write_results_table(run)
    figures = _figures(rep, run)
    rep["figures"] = [p.name for p in figures]
    md = render_markdown(rep)
    paths = {"json": run / "report.json", "markdown": run / "report.md", "html": run / "report.html"}
    paths["json"].write_text(json.dumps(rep, indent=2, default=str))
    paths["markdown"].write_text(md)
    paths["html"].write_text(render_html(md))
    for p in figures:
        paths[p.stem] = p
    return paths

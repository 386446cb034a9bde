"""`memora tools`, `memora tool` and `memora perf tools`: parse, call the library, render."""

from __future__ import annotations

import json
import typing

import click
import polars as pl

from memora_graph.output import output_options, render

# Where each tool's records are in its result, for --table / --csv / --nl.
_RECORDS = ("results", "routines", "preferences", "visible_objects", "state_history")


def _arg_value(spec, name: str, raw: str):
    field = spec.args.model_fields.get(name)
    if field is None:  # let validation name the unknown argument
        return raw
    types = typing.get_args(field.annotation) or (field.annotation,)
    if str in types:
        return raw
    try:
        return json.loads(raw)
    except (json.JSONDecodeError, RecursionError):  # too deeply nested: let validation refuse the text
        return raw


def _flat(value):
    if isinstance(value, (dict, list)):
        return json.dumps(value, ensure_ascii=False)
    return value


# Left out of --table (still in --json / --csv / --nl): long or secondary fields.
_VERBOSE = {"detailed_narrative", "action_breakdown", "evidence", "supporting_episodes", "source_videos", "keywords",
            "duplicates", "time_seen_seconds", "first_seen", "last_seen", "processor", "visual_properties", "places",
            "objects", "evidence_summary", "features", "kind", "object_id", "source", "zones"}


def _short(value, width: int = 60):
    if isinstance(value, list):
        parts = [v.get("name") or v.get("action") or v.get("object") or json.dumps(v) if isinstance(v, dict) else str(v)
                 for v in value]
        value = ", ".join(parts)
    elif isinstance(value, dict):
        value = json.dumps(value, ensure_ascii=False)
    if isinstance(value, str) and len(value) > width:
        value = value[: width - 1] + "…"
    return value


def _compact(row: dict) -> dict:
    out = {}
    for k, v in row.items():
        if k in _VERBOSE:
            continue
        if k == "score":
            out.update({f"s_{s}": v.get(s) for s in ("vector", "keyword", "graph")})
            out["fused"] = v.get("fused")
        elif isinstance(v, dict):
            out.update({f"{k}.{kk}": _short(vv) for kk, vv in v.items() if not isinstance(vv, (dict, list))})
        else:
            out[k] = _short(v)
    return out


def records_frame(result: dict, compact: bool = False) -> pl.DataFrame:
    """The records of a tool result as a flat frame (nested fields as JSON text); `compact`
    keeps the fields a table can show and splits the score breakdown into columns."""
    if result.get("tool") == "search":
        rows = [{"store": c, **r} for c in ("objects", "activities", "places", "patterns") for r in result.get(c, [])]
        if compact:  # one shape for every store: which record, what it says, why it was returned
            rows = [{"store": r["store"],
                     "id": r.get("entity_id") or r.get("segment_id") or r.get("place_id") or r.get("pattern_id"),
                     "text": _short(r.get("description") or r.get("summary") or r.get("name"), 70),
                     "similarity": r.get("similarity"), "score": r.get("score", {})} for r in rows]
    else:
        key = next((k for k in _RECORDS if k in result), None)
        rows = result.get(key, []) if key else [{k: v for k, v in result.items() if k not in ("arguments",)}]
    if not rows:
        return pl.DataFrame()
    if compact:
        rows = [_compact(r) for r in rows]
    cols = list(dict.fromkeys(k for r in rows for k in r))
    return pl.DataFrame([{c: _flat(r.get(c)) for c in cols} for r in rows], infer_schema_length=None)


@click.command("tools")
@output_options
def tools_cmd(fmt):
    """List the retrieval tools with their arguments.

    --json prints the OpenAI function schemas an agent advertises (every tool).

    \b
    Examples:
      memora tools
      memora tools --json
    """
    from memora_graph.retrieve import get_tool, tool_names, tool_schemas

    if fmt == "json":
        click.echo(json.dumps(tool_schemas(tool_names()), indent=2))
        return
    rows = []
    for name in tool_names():
        spec = get_tool(name)
        args = []
        for arg, f in spec.args.model_fields.items():
            t = getattr(f.annotation, "__name__", str(f.annotation).replace("typing.", ""))
            args.append(f"{arg}: {t}" + ("" if f.is_required() else f" = {f.default!r}"))
        rows.append({"tool": name, "arguments": ", ".join(args), "advertised": spec.advertised,
                     "description": spec.description})
    click.echo(render(pl.DataFrame(rows), fmt))


@click.command("tool")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.argument("name")
@click.argument("text", required=False)
@click.option("--participant", required=True, help="Whose memory to search (P01); tools never see another's.")
@click.option("--arg", "args", type=(str, str), multiple=True, metavar="NAME VALUE",
              help="A tool argument (see `memora tools`). Repeatable.")
@click.option("--recipe", type=click.Choice(["inprocess", "fts", "kuzu", "vector"]), default="inprocess", show_default=True,
              help="Retrieval variant (see memora_graph/retrieve/search.py).")
@output_options
def tool_cmd(bank, name, text, participant, args, recipe, fmt):
    """Call one retrieval tool on one participant's memory.

    TEXT, if given, fills the tool's first argument (query, object_query, goal_query,
    time_seconds). --json prints the whole result (records, evidence ids, score breakdown);
    --table / --csv / --nl print its records.

    \b
    Examples:
      memora tool banks/epic get_routine_skill "wash the bowl" --participant P03
      memora tool banks/epic search_objects --participant P03 --arg query bowl --arg top_k 5 --json
      memora tool banks/epic get_preferences "spatula or fork for eggs" --participant P04
      memora tool banks/epic get_object_history plate --participant P01
      memora tool banks/epic get_state_at_time 120 --participant P01 --arg video P01_102
    """
    from memora_graph.retrieve import MemoryView, call_tool, get_tool

    spec = get_tool(name)
    arguments = {k: _arg_value(spec, k, v) for k, v in args}
    if text is not None:
        first = next(iter(spec.args.model_fields))
        arguments.setdefault(first, _arg_value(spec, first, text))
    with MemoryView.open(bank, participant, config=recipe) as view:
        result = call_tool(view, name, arguments)
    if fmt == "json":
        click.echo(json.dumps(result, indent=2, ensure_ascii=False, default=str))
        return
    if fmt == "table":
        head = {k: v for k, v in result.items() if k not in _RECORDS and k not in ("objects", "activities", "places",
                                                                                    "patterns", "evidence")}
        click.echo(json.dumps(head, ensure_ascii=False, default=str)[:2000])
    click.echo(render(records_frame(result, compact=fmt == "table"), fmt))


@click.command("tools")
@click.argument("bank", type=click.Path(exists=True, file_okay=False), default="banks/epic")
@click.option("--participants", default="all", show_default=True, help="Comma-separated ids or 'all'.")
@click.option("--queries", "n_queries", default=10, show_default=True, help="Queries per tool and participant.")
@click.option("--recipes", default="inprocess,fts,kuzu", show_default=True,
              help="Retrieval variants to time (see memora_graph/retrieve/search.py).")
@click.option("--hnsw/--no-hnsw", default=True, show_default=True,
              help="Also build HNSW indexes on a temporary copy of a few participants and measure them.")
@output_options
def perf_tools_cmd(bank, participants, n_queries, recipes, hnsw, fmt):
    """Time every tool over a fixed query set: p50 / p95 per call (query embedding included),
    next to the exact numpy top-k floor, and recall@10 of every vector search against exact.

    Cold = a query seen for the first time (it is embedded); warm = its embedding is cached
    (an agent repeating a query, or `search` fanning one query out to every store).

    \b
    Examples:
      memora perf tools banks/epic
      memora perf tools banks/epic --participants P01,P03 --queries 5 --no-hnsw
    """
    from memora_graph.retrieve.perf import run_perf

    pids = None if participants == "all" else [p.strip() for p in participants.split(",") if p.strip()]
    report = run_perf(bank, pids, n_queries=n_queries, recipes=[r.strip() for r in recipes.split(",") if r.strip()],
                      hnsw=hnsw, echo=click.echo)
    click.echo(render(report.latency, fmt))
    if fmt == "table":
        click.echo(render(report.recall, fmt))
        for line in report.summary:
            click.echo(line)

"""`memora tools` and `memora tool`: parse, call the library, render."""

from __future__ import annotations

import json

from typing import TYPE_CHECKING

import click

from memora_graph.cli.options import FAMILY, RECIPE, check_participant_option, output_options
from memora_graph.output import render
from memora_graph.text import counted

if TYPE_CHECKING:
    import polars as pl

# Where each tool's records are in its result, for --table / --csv / --nl.


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


_ID_FIELDS = ("entity_id", "segment_id", "place_id", "pattern_id", "routine_id", "preference_id", "event_id", "id")


def records_frame(result, compact: bool = False) -> pl.DataFrame:
    """The records of a typed tool result as a flat frame (nested fields as JSON text). A result
    with several lists (a unified `search`) gets one shape for every store: which record, what it
    says, why it was returned. `compact` keeps the fields a table can show and splits the score
    breakdown into columns. A result without record lists is one row of its fields."""
    import polars as pl

    records = list(result.records())
    kinds = list(dict.fromkeys(k for k, _ in records))
    if len(kinds) > 1:
        rows = [{"store": k, **r.model_dump(mode="json")} for k, r in records]
        if compact:
            rows = [{"store": r["store"], "id": next((r[f] for f in _ID_FIELDS if r.get(f)), None),
                     "text": _short(rec.text(), 70), "similarity": r.get("similarity"), "score": r.get("score") or {}}
                    for r, (_, rec) in zip(rows, records)]
    elif records:
        rows = [r.model_dump(mode="json") for _, r in records]
    else:
        rows = [{k: v for k, v in result.as_json().items() if k not in ("arguments",)}]
    if not rows:
        return pl.DataFrame()
    if compact:
        rows = [_compact(r) for r in rows]
    cols = list(dict.fromkeys(k for r in rows for k in r))
    return pl.DataFrame([{c: _flat(r.get(c)) for c in cols} for r in rows], infer_schema_length=None)


_HEAD_SKIP = {"tool", "participant", "arguments", "evidence", "notes"}


def _line(value, width: int = 110) -> str:
    text = " ".join(str(_short(value, width)).split())
    return text if len(text) <= width else text[: width - 1] + "…"


def result_summary(res) -> str:
    """A tool result for a person reading a terminal: what was asked, the result's own fields (a
    found object, its current state, a video's length), then one numbered line per record (its id,
    what it says, its similarity) in rank order, list by list. Every field is in --json; the
    records' fields one column each in --csv / --nl."""
    result = res.as_json()
    arguments = ", ".join(f"{k}={v!r}" for k, v in (result.get("arguments") or {}).items() if v not in (None, ""))
    lines = [f"{result.get('tool', '?')} on {result.get('participant', '?')}'s memory ({arguments})"]
    lists = set(res._lists)
    for key, value in result.items():
        if key in _HEAD_SKIP or key in lists or value in (None, "", [], {}):
            continue
        if isinstance(value, list) and value and isinstance(value[0], dict):
            value = f"{counted(len(value), 'entry', 'entries')} (--json shows them)"
        lines.append(f"  {key}: {_line(value)}")
    records = list(res.records())
    by_list: dict[str, list] = {}
    for name, rec in records:
        by_list.setdefault(name, []).append(rec)
    for name, recs in by_list.items():
        lines.append(f"{name} ({counted(len(recs), 'record')}):")
        for i, rec in enumerate(recs, 1):
            data = rec.model_dump(mode="json")
            rid = next((data[f] for f in _ID_FIELDS if data.get(f)), "")
            sim = data.get("similarity")
            tail = f"  (similarity {sim:.2f})" if isinstance(sim, (int, float)) else ""
            lines.append(f"{i:>3}. {rid}  {_line(rec.text() or json.dumps(data, ensure_ascii=False), 100)}{tail}")
    if not records:
        lines.append("(no records)")
    for note in result.get("notes") or []:
        lines.append(f"note: {_line(note, 200)}")
    lines.append("(--json: the whole result with evidence ids and scores; --csv / --nl: every field of the records)")
    return "\n".join(lines)


@click.command("tools")
@click.option("--memory", "family", type=FAMILY, default=None,
              help="Only the tools of one memory representation: memora (default for --json), flat1d, graph2d.")
@output_options(json_help="A JSON array: the OpenAI function schema of every tool of the family.")
def tools_cmd(family, fmt):
    """List the retrieval tools with their arguments, the store each reads, and the memory
    representation (family) they belong to: MEMORA's typed stores, or a baseline's.

    --json prints the OpenAI function schemas an agent advertises (every tool of the family).

    \b
    Examples:
      memora tools
      memora tools --memory flat1d
      memora tools --json
    """
    import polars as pl

    from memora_graph.retrieve.registry import specs, tool_names, tool_schemas

    if fmt == "json":
        family = family or "memora"
        click.echo(json.dumps(tool_schemas(tool_names(family), family), indent=2))
        return
    rows = []
    for spec in specs(family):
        args = []
        for arg, f in spec.args.model_fields.items():
            t = getattr(f.annotation, "__name__", str(f.annotation).replace("typing.", ""))
            args.append(f"{arg}: {t}" + ("" if f.is_required() else f" = {f.default!r}"))
        rows.append({"memory": spec.family, "tool": spec.name, "arguments": ", ".join(args), "store": spec.store,
                     "advertised": spec.advertised, "description": spec.description})
    click.echo(render(pl.DataFrame(rows), fmt))


@click.command("tool")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.argument("name")
@click.argument("text", required=False)
@click.option("--participant", required=True, callback=check_participant_option,
              help="Whose memory to search (P01); tools never see another's.")
@click.option("--arg", "args", type=(str, str), multiple=True, metavar="NAME VALUE",
              help="A tool argument (see `memora tools`). Repeatable.")
@click.option("--recipe", type=RECIPE, default=None,
              help="Retrieval variant of the MEMORA tools (see memora_graph/retrieve/search.py). Default: "
                   "'inprocess'; 'hnsw' from HNSW_MIN_SEGMENTS segments on, for a memory that has its indexes, once a "
                   "measured size sets it (none yet).")
@click.option("--memory", "family", type=FAMILY, default="memora", show_default=True,
              help="Which memory the tool reads: memora, or a baseline's representation (flat1d, graph2d).")
@output_options(json_help="One JSON object: the whole result (records, evidence ids, score breakdown).")
def tool_cmd(bank, name, text, participant, args, recipe, family, fmt):
    """Call one retrieval tool on one participant's memory.

    TEXT, if given, fills the tool's positional argument (query, object_query, goal_query,
    time_seconds: `memora tools` lists them). --json prints the whole result (records, evidence
    ids, score breakdown); by default (--table) a summary: the result's own fields, then one
    numbered line per record (id, what it says, similarity); --csv / --nl print every field of
    its records.

    \b
    Examples:
      memora tool banks/epic get_routine_skill "wash the bowl" --participant P03
      memora tool banks/epic search_objects --participant P03 --arg query bowl --arg top_k 5 --json
      memora tool banks/epic get_preferences "spatula or fork for eggs" --participant P04
      memora tool banks/epic get_object_history plate --participant P01
      memora tool banks/epic get_state_at_time 120 --participant P01 --arg video P01_102
      memora tool banks/epic search "wash the plate" --participant P01 --memory flat1d
    """
    from memora_graph.retrieve.registry import call_tool, get_family, get_tool, parse_arguments
    from memora_graph.retrieve.view import MemoryView

    spec = get_tool(name, family)
    raw = dict(args)
    if text is not None:
        raw.setdefault(spec.first_argument, text)
    arguments = parse_arguments(spec, raw)
    if family == "memora":
        with MemoryView.open(bank, participant, config=recipe) as view:
            res = call_tool(view, name, arguments)
    else:
        res = call_tool(get_family(family).open(bank, participant), name, arguments, family)
    result = res.as_json()
    if fmt == "json":
        click.echo(json.dumps(result, indent=2, ensure_ascii=False, default=str))
        return
    if fmt == "table":
        click.echo(result_summary(res))
        return
    click.echo(render(records_frame(res), fmt))

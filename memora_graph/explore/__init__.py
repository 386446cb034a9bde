"""`memora explore`: one participant's memory as a single self-contained HTML page.

The page shows a timeline of videos and 10 s segments coloured by place (each video's tasks
as a band under its row, named by goal, with their stages), swimlanes of object
state histories with the editor's decisions, the routines and preferences with their supporting
segments, and a small graph of routines, objects and places, with filters by object and place.
Its data is read here through named queries and embedded as JSON; the page's script and styles
(explorer.js, explorer.css, hand-written, no library) are inlined. It fetches nothing when opened
(its Content-Security-Policy forbids it), so it can be mailed or archived as one file.
"""

from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from importlib import resources
from pathlib import Path

from memora_graph.bank import Bank

_QUERIES = {
    "videos": "_explore_videos", "segments": "_explore_segments", "places": "_explore_places",
    "entities": "_explore_entities", "events": "_explore_events", "edits": "_explore_edits",
    "routines": "_explore_routines", "preferences": "_explore_preferences",
}


def explorer_data(bank_path: str | Path, participant: str) -> dict:
    """Everything the page shows, as plain JSON-ready lists (one read-only open of the database)."""
    bank = Bank(bank_path)
    with bank.open(participant) as store:
        data = {key: store.fetch(name, participant=participant) for key, name in _QUERIES.items()}
        evidence = {r["id"]: sorted(set(r["linked"])) for r in store.fetch("_explore_evidence", participant=participant)}
        # tasks on the timeline (a bank consolidated before task memory has no Task table: none shown)
        data["tasks"] = [{**t, "stages": json.loads(t["stages"] or "{}"), "steps": None}
                         for t in store.fetch("_tasks_all", participant=participant)] if "Task" in store.tables() else []
        links: dict[str, list[str]] = {}
        for r in store.fetch("_tool_inferred_links", participant=participant):
            links.setdefault(r["id"], []).append(r["entity"])
    for kind in ("routines", "preferences"):
        for r in data[kind]:
            r["segments"] = evidence.get(r["id"], [])
            r["entities"] = sorted(set(links.get(r["id"], [])))
    entry = bank.manifest()["participants"][participant]
    return {"participant": participant, "bank": str(bank.path), "generated_at":
            datetime.now(timezone.utc).isoformat(timespec="seconds"), "inferred": entry.get("inferred"), **data}


def _asset(name: str) -> str:
    return resources.files(__package__).joinpath(name).read_text(encoding="utf-8")


def embed_json(data: dict) -> str:
    """JSON that is safe inside <script type="application/json">: every '<' is written as
    \\u003c, so no value can close the element ('</script>') or open a comment ('<!--')."""
    return json.dumps(data, ensure_ascii=False, separators=(",", ":"), default=str).replace("<", "\\u003c")


def render_page(data: dict) -> str:
    title = f"memora explorer: {data['participant']}"
    page = _asset("explorer.html")
    # the title first: the markers are filled in order, each once, so no inserted text is read as a marker
    for marker, value in (("{{TITLE}}", title.replace("&", "&amp;").replace("<", "&lt;")),
                          ("/*STYLE*/", _asset("explorer.css")), ("/*SCRIPT*/", _asset("explorer.js")),
                          ("/*DATA*/", embed_json(data))):
        page = page.replace(marker, value, 1)
    return page


def write_explorer(bank_path: str | Path, participant: str, out: str | Path) -> tuple[Path, dict]:
    """Write the page for one participant to `out` (written aside and renamed: never half-written)."""
    data = explorer_data(bank_path, participant)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    try:
        tmp.write_text(render_page(data), encoding="utf-8")
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out, data

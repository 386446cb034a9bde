"""Named, parameterized Cypher queries loaded from queries/*.cypher.

Each file holds one query with a header:

    // name: object_history            (must match the file name)
    // description: An object's state history in time order.
    // params: participant, object
    // mode: read                       (read | write)
    // scope: participant               (participant | database)
    // bound: limit 1000                 (or `page video`: what bounds the rows it returns; see below)

`bound` says what bounds a query's rows (issue 36: every named query a server or the explorer
offers is bounded by what it returns): `limit N`, where the body ends with `LIMIT N` (an
aggregate of a few rows states it too), or `page P`, where the query reads one page keyed by its
`$P` (a video, an object, a record: `videos` lists the videos). Checked at load time.

At load time the declared params must equal the $tokens of the body, and a query that touches
participant data must take $participant. A `scope: database` query reads or writes the
database itself (catalog, schema records, row counts of every table), not one participant's
records through their tables.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from memora_graph.errors import QueryError
from memora_graph.paths import QUERIES_DIR

PARTICIPANT_TABLES = (
    "Participant", "Video", "Segment", "Place", "Entity", "StateEvent", "EditOp", "Routine", "Preference",
    "ModelCall", "Remembered",
)
_TOKEN = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")
_LABEL = re.compile(r":\s*(" + "|".join(PARTICIPANT_TABLES) + r")\b")
_HEADER = re.compile(r"^//\s*(name|description|params|mode|example|scope|bound)\s*:\s*(.*)$")
_LIMIT = re.compile(r"\bLIMIT\s+(\d+)\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class NamedQuery:
    name: str
    description: str
    params: tuple[str, ...]
    mode: str
    cypher: str
    path: Path
    example: str = ""
    scope: str = "participant"
    bound: str = ""  # "limit N" or "page P" (see the module); "" where none is stated

    @property
    def limit(self) -> int | None:
        return int(self.bound.split()[1]) if self.bound.startswith("limit ") else None

    @property
    def page(self) -> str | None:
        return self.bound.split()[1] if self.bound.startswith("page ") else None

    @property
    def writes(self) -> bool:
        return self.mode == "write"


def _strip_strings(body: str) -> str:
    return re.sub(r"'(?:[^'\\]|\\.)*'|\"(?:[^\"\\]|\\.)*\"", "''", body)


def parse_query(path: Path) -> NamedQuery:
    header: dict[str, str] = {}
    body_lines = []
    for line in path.read_text().splitlines():
        m = _HEADER.match(line.strip())
        if m and not body_lines:
            header[m.group(1)] = m.group(2).strip()
        elif line.strip().startswith("//") and not body_lines:
            continue
        else:
            body_lines.append(line)
    cypher = "\n".join(body_lines).strip().rstrip(";")
    name = header.get("name", path.stem)
    if name != path.stem:
        raise QueryError(f"{path}: header name '{name}' does not match the file name '{path.stem}'")
    if not cypher:
        raise QueryError(f"{path}: no Cypher after the header")
    declared = tuple(p.strip() for p in header.get("params", "").split(",") if p.strip())
    used = set(_TOKEN.findall(_strip_strings(cypher)))
    if set(declared) != used:
        missing = sorted(used - set(declared))
        extra = sorted(set(declared) - used)
        raise QueryError(
            f"{path}: declared params do not match the query's $tokens"
            + (f"; undeclared: {', '.join(missing)}" if missing else "")
            + (f"; declared but unused: {', '.join(extra)}" if extra else "")
        )
    scope = header.get("scope", "participant")
    if scope not in ("participant", "database"):
        raise QueryError(f"{path}: scope must be participant or database, not {scope!r}")
    if _LABEL.search(cypher) and (scope == "database" or "participant" not in declared):
        raise QueryError(f"{path}: reads participant data but does not take $participant"
                         + (" (a scope: database query must not name participant tables)" if scope == "database" else ""))
    mode = header.get("mode", "read")
    if mode not in ("read", "write"):
        raise QueryError(f"{path}: mode must be read or write, not {mode!r}")
    bound = " ".join(header.get("bound", "").split())
    if bound:
        kind, _, what = bound.partition(" ")
        end = _LIMIT.search(cypher)
        if kind == "limit" and not (what.isdigit() and end and end.group(1) == what):
            raise QueryError(f"{path}: bound: {bound!r} states a LIMIT its query does not end with"
                             + (f" (it ends with LIMIT {end.group(1)})" if end else ""))
        if kind == "page" and what not in declared:
            raise QueryError(f"{path}: bound: {bound!r} names a page key that is not one of its params")
        if kind not in ("limit", "page"):
            raise QueryError(f"{path}: bound must be `limit N` or `page PARAM`, not {bound!r}")
    return NamedQuery(name, header.get("description", ""), declared, mode, cypher, path, header.get("example", ""), scope,
                      bound)


@lru_cache(maxsize=4)
def load_queries(folder: Path = QUERIES_DIR) -> dict[str, NamedQuery]:
    if not folder.is_dir():
        raise QueryError(f"{folder}: queries folder not found (install the project with `pip install -e .` from its checkout)")
    return {q.name: q for q in (parse_query(p) for p in sorted(folder.glob("*.cypher")))}


def get_query(name: str) -> NamedQuery:
    queries = load_queries()
    if name not in queries:
        public = ", ".join(n for n in sorted(queries) if not n.startswith("_"))
        raise QueryError(f"no named query '{name}'; known queries: {public}")
    return queries[name]


def bind(query: NamedQuery, params: dict) -> dict:
    missing = [p for p in query.params if p not in params]
    extra = [p for p in params if p not in query.params]
    if missing or extra:
        raise QueryError(
            f"query '{query.name}' takes {', '.join(query.params) or 'no params'}"
            + (f"; missing: {', '.join(missing)}" if missing else "")
            + (f"; unknown: {', '.join(extra)}" if extra else "")
        )
    return dict(params)

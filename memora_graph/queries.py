"""Named, parameterized Cypher queries loaded from queries/*.cypher.

Each file holds one query with a header:

    // name: object_history            (must match the file name)
    // description: An object's state history in time order.
    // params: participant, object
    // mode: read                       (read | write)
    // scope: participant               (participant | database)

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
_HEADER = re.compile(r"^//\s*(name|description|params|mode|example|scope)\s*:\s*(.*)$")


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
    return NamedQuery(name, header.get("description", ""), declared, mode, cypher, path, header.get("example", ""), scope)


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

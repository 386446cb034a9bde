"""The attack corpus of issue 12 ("Trust the bank"): statements the read guard must refuse, the
forms they are hidden in, statements it must let through, and bad inputs for every command.

Placeholders in the statements: {bank} the bank directory, {other} another participant's
database file, {out} a directory an attack would write into.
"""

from __future__ import annotations

import re

# (kind, statement): every one of these reaches nothing in Kùzu without --write, and the kinds
# other than "data" not even with --write.
FORBIDDEN = [
    # files
    ("file", "COPY (RETURN 'x' AS a) TO '{bank}/manifest.json'"),
    ("file", "COPY (MATCH (e:Entity) RETURN e.name AS name) TO '{out}/entities.csv'"),
    ("file", "COPY (RETURN 1 AS a) TO '{out}/x.parquet'"),
    ("file", "COPY Entity FROM '{out}/entities.csv'"),
    ("file", "COPY Participant FROM (RETURN 'X1' AS id, 'X1' AS participant)"),
    ("file", "EXPORT DATABASE '{out}/export'"),
    ("file", "EXPORT DATABASE '{out}/export2' (FORMAT='parquet')"),
    ("file", "IMPORT DATABASE '{out}/export'"),
    ("file", "LOAD FROM '/etc/passwd' (header=false, delim=':', file_format='csv') RETURN *"),
    ("file", "LOAD WITH HEADERS (a STRING) FROM '/etc/passwd' (file_format='csv') RETURN *"),
    ("file", "LOAD FROM '{bank}/manifest.json' RETURN *"),
    ("file", "MATCH (e:Entity) WITH e LIMIT 1 LOAD FROM '/etc/passwd' (header=false, delim=':', file_format='csv') RETURN *"),
    ("file", "UNWIND [1] AS i LOAD FROM '/etc/hostname' (header=false, file_format='csv') RETURN *"),
    # extensions (native code)
    ("extension", "LOAD EXTENSION '{out}/evil.kuzu_extension'"),
    ("extension", "LOAD json"),
    ("extension", "INSTALL json"),
    ("extension", "INSTALL httpfs FROM 'http://127.0.0.1:9/'"),
    ("extension", "UNINSTALL json"),
    ("extension", "UPDATE json"),
    ("extension", "FORCE INSTALL json"),
    # other databases
    ("database", "ATTACH '{other}' AS o (dbtype kuzu)"),
    ("database", "ATTACH '{other}' AS o (dbtype kuzu, skip_unsupported_table=true)"),
    ("database", "USE o"),
    ("database", "DETACH o"),
    ("database", "CHECKPOINT"),
    # data writes
    ("data", "CREATE (:Participant {id: 'X99', participant: 'X99'})"),
    ("data", "MATCH (e:Entity) SET e.name = 'changed'"),
    ("data", "MATCH (e:Entity) DELETE e"),
    ("data", "MATCH (e:Entity) DETACH DELETE e"),
    ("data", "MATCH (e:Entity) REMOVE e.name"),
    ("data", "MERGE (:Participant {id: 'X98', participant: 'X98'})"),
    ("data", "MATCH (e:Entity) WITH e LIMIT 1 CREATE (:Participant {id: 'X97', participant: 'X97'})"),
    ("data", "UNWIND [1, 2] AS i CREATE (:Participant {id: 'X' + CAST(i AS STRING), participant: 'X'})"),
    ("data", "MERGE (p:Participant {id: 'P09'}) ON CREATE SET p.participant = 'x' ON MATCH SET p.participant = 'y'"),
    ("data", "MATCH (a:Entity), (b:Place) WITH a, b LIMIT 1 CREATE (a)-[:AT {video: 'v', t: 0.0}]->(b)"),
    # schema
    ("schema", "CREATE NODE TABLE Evil(id STRING PRIMARY KEY)"),
    ("schema", "CREATE REL TABLE EVIL_R(FROM Entity TO Entity)"),
    ("schema", "DROP TABLE Entity"),
    ("schema", "ALTER TABLE Entity ADD evil STRING"),
    ("schema", "ALTER TABLE Entity RENAME TO Gone"),
    ("schema", "COMMENT ON TABLE Entity IS 'evil'"),
    ("schema", "CREATE MACRO evil(x) AS x + 1"),
    ("schema", "CREATE SEQUENCE evil_seq"),
    ("schema", "DROP SEQUENCE evil_seq"),
    ("schema", "CREATE TYPE evil AS STRING"),
    ("schema", "CALL CREATE_FTS_INDEX('Entity', 'evil_fts', ['name'])"),
    ("schema", "CALL DROP_FTS_INDEX('Entity', 'entity_fts')"),
    ("schema", "CALL CREATE_VECTOR_INDEX('Entity', 'evil_vec', 'embedding')"),
    ("schema", "CALL DROP_VECTOR_INDEX('Entity', 'evil_vec')"),
    # transactions
    ("transaction", "BEGIN TRANSACTION"),
    ("transaction", "BEGIN TRANSACTION READ ONLY"),
    ("transaction", "COMMIT"),
    ("transaction", "ROLLBACK"),
    # configuration and procedures that are not read-only
    ("config", "CALL threads = 1"),
    ("config", "CALL timeout=1"),
    ("config", "CALL checkpoint_threshold = 1"),
    ("procedure", "CALL file_info() RETURN *"),
    ("procedure", "CALL read_parquet('{out}/x.parquet') RETURN *"),
    ("procedure", "CALL project_graph('g', ['Entity'], [])"),
    ("procedure", "CALL clear_warnings()"),
    ("procedure", "CALL _cache_array_column_locally('Entity', 'embedding')"),
    # more than one statement (Kùzu 0.11.3 crashes with a segmentation fault)
    ("multi", "RETURN 1 AS a; RETURN 2 AS b"),
    ("multi", "MATCH (e:Entity) RETURN e.name; CHECKPOINT"),
    ("multi", "ATTACH '{other}' AS o (dbtype kuzu); USE o; COPY (MATCH (e:Entity) RETURN e.name) TO '{out}/leak.csv'"),
    ("multi", "RETURN 1 AS a;;"),
]

# What --write still refuses: everything but the data writes.
NEVER = [(k, s) for k, s in FORBIDDEN if k != "data"]

_TOKEN = re.compile(r"'[^']*'|[A-Za-z_][A-Za-z0-9_]*|\S")


def _recase(statement: str, how) -> str:
    """Change the case of every bare word (keywords are case-insensitive), not of string literals."""
    return re.sub(r"'[^']*'|[A-Za-z_][A-Za-z0-9_]*", lambda m: m.group() if m.group().startswith("'") else how(m.group()),
                  statement)


def _alternate(word: str) -> str:
    return "".join(c.upper() if i % 2 else c.lower() for i, c in enumerate(word))


def _between_tokens(statement: str, glue: str) -> str:
    return glue.join(_TOKEN.findall(statement))


# Forms an attack hides in: (name, function of the statement).
DISGUISES = [
    ("as written", lambda s: s),
    ("lower case", lambda s: _recase(s, str.lower)),
    ("mixed case", lambda s: _recase(s, _alternate)),
    ("line comment before", lambda s: "// just a read\n" + s),
    ("block comment before", lambda s: "/* MATCH (e) RETURN e */ " + s),
    ("comments between tokens", lambda s: _between_tokens(s, " /* x */ ")),
    ("split over lines", lambda s: _between_tokens(s, "\n  ")),
    ("tabs and CRLF", lambda s: _between_tokens(s, "\t\r\n")),
    ("trailing semicolon and comment", lambda s: s + "; // done"),
    ("after EXPLAIN", lambda s: "EXPLAIN " + s),
    ("after PROFILE", lambda s: "PROFILE " + s),
    ("second statement", lambda s: "MATCH (e:Entity) RETURN count(e) AS n; " + s),
    ("after a read clause", lambda s: "MATCH (e:Entity) WITH e LIMIT 1 " + s),
    ("after a comment Kùzu ends late", lambda s: "RETURN 1 AS a /* **/ */ ; " + s),
]


def attacks(forbidden=FORBIDDEN) -> list[tuple[str, str, str]]:
    """(kind, disguise, statement) for every forbidden statement in every disguise."""
    return [(kind, name, f(s)) for kind, s in forbidden for name, f in DISGUISES]


# Reads that mention forbidden words only inside strings, comments, backticks or as names, and
# the read-only procedures: the guard lets them through and Kùzu runs them on a bank.
ALLOWED = [
    "MATCH (e:Entity) WHERE e.name = 'copy' RETURN e.name",
    "MATCH (e:Entity) WHERE e.name = 'COPY (RETURN 1) TO \\'/tmp/x\\'' RETURN count(e) AS n",
    "MATCH (e:Entity) WHERE e.name <> \"LOAD FROM '/etc/passwd' RETURN *\" RETURN count(e) AS n",
    "MATCH (e:Entity) WHERE e.name = 'a; RETURN 2; ATTACH' RETURN count(e) AS n",
    "MATCH (e:Entity) // COPY (RETURN 1) TO 'x'; DROP TABLE Entity\nRETURN count(e) AS n",
    "MATCH (e:Entity) /* ATTACH 'x' AS o; USE o; CHECKPOINT */ RETURN count(e) AS n",
    "RETURN 1 /* **/ ; COPY (RETURN 1) TO '{out}/comment.csv' /* */ AS n",  # one comment, as Kùzu reads it
    "RETURN 'it\\'s a SET of DELETE and CREATE' AS `COPY`, 2 AS `LOAD`",
    "RETURN 1 AS copy, 2 AS load, 3 AS set",
    "WITH {set: 1, copy: 2, `delete`: 3} AS m RETURN m.set AS s, m.copy AS c",
    "MATCH (e:Entity) WHERE e.participant = $participant RETURN e.name AS name, e.state AS state ORDER BY name LIMIT 5",
    "match (e:Entity)\n  where e.participant = $participant\n  return count(*) as n;",
    "MATCH (e:Entity)-[h:HAS_STATE]->(s:StateEvent) WHERE e.participant = $participant AND e.object_id = 'plate' "
    "RETURN s.video, s.t, s.state ORDER BY s.video, s.t, h.ord",
    "OPTIONAL MATCH (p:Place) WHERE p.name STARTS WITH 'sink' RETURN count(p) AS n",
    "UNWIND [1, 2, 3] AS i RETURN sum(i) AS total",
    "RETURN CASE WHEN 1 > 0 THEN CASE WHEN 2 > 1 THEN 'set' ELSE 'delete' END ELSE 'x' END AS v",
    "MATCH (e:Entity) RETURN count(e) AS n UNION ALL MATCH (p:Place) RETURN count(p) AS n",
    "CALL show_tables() RETURN name, type ORDER BY name",
    "CALL table_info('Entity') RETURN name",
    "CALL show_indexes() RETURN *",
    "CALL show_connection('HAS_STATE') RETURN *",
    "CALL db_version() RETURN *",
    "CALL current_setting('threads') RETURN *",
    "CALL show_functions() RETURN count(*) AS n",
    "EXPLAIN MATCH (e:Entity) RETURN e.name",
    "PROFILE MATCH (e:Entity) RETURN count(e) AS n",
    "MATCH (e:Entity) RETURN e.`name` AS `set`",
    "RETURN CAST(1 AS STRING) AS x",
]

# Parameters that used to traceback (TypeError, RecursionError, ValueError) or say nothing useful.
BAD_PARAMS = [
    ("participant", '["P09"]'), ("participant", '{"a": 1}'), ("participant", "9"), ("participant", ""),
    ("participant", "null"), ("participant", "P9"), ("participant", "p09"), ("participant", "../P09"),
    ("participant", "[" * 5000), ("participant", '"P09'), ("x", "[" * 100000), ("x", "[1, \"a\"]"), ("x", "[]"),
    ("x", "{}"), ("x", "99999999999999999999999999"), ("x", "Infinity"), ("x", "NaN"), ("x", "-Infinity"),
    ("x", "[[1], [2, [3]]]"), ("x", '{"": 1}'), ("x", '[' * 9 + ']' * 9), ("bad name", "1"), ("1x", "1"),
]


# Manifests a bank can be left with (hand edits, a disk filling up, another program): name -> bytes.
BAD_MANIFESTS = {
    "not JSON": b"{not json",
    "a JSON list": b"[]",
    "a JSON string": b'"manifest"',
    "a JSON number": b"42",
    "JSON null": b"null",
    "empty": b"",
    "binary": bytes(range(256)),
    "deeply nested": b"[" * 100000 + b"]" * 100000,
    "no participants": b'{"format": 1}',
    "participants a list": b'{"format": 1, "participants": ["P09"]}',
    "a participant not a map": b'{"format": 1, "participants": {"P09": 5}}',
    "a bad participant id": b'{"format": 1, "participants": {"../../etc": {"counts": {}}}}',
    "counts not a map": b'{"format": 1, "participants": {"P09": {"counts": [1, 2]}}}',
    "unknown format": b'{"format": 99, "participants": {}}',
    "format a list": b'{"format": [1], "participants": {}}',
    "writing a string": b'{"format": 1, "participants": {}, "writing": "P09"}',
    "writing a list": b'{"format": 1, "participants": {}, "writing": ["P09"]}',
    "writing a bad id": b'{"format": 1, "participants": {}, "writing": {"P09\\n": {"op": "build"}}}',
    "integrity a string": b'{"format": 1, "participants": {"P09": {"counts": {}, "integrity": "ok"}}}',
    "a participant id with a newline": b'{"format": 1, "participants": {"P09\\n": {"counts": {}}}}',
}


def bad_cli_inputs(bank: str, scratch: str) -> list[tuple[str, list[str]]]:
    """(what, argv) of bad parameters and bad paths for every command that takes them. `bank` is
    a good bank (P09, P37); `scratch` a directory with `afile` (a file), `empty/` (an empty
    directory), `orphan/` (a database file but no manifest) and `damaged-NAME/` banks whose
    manifest is BAD_MANIFESTS[NAME]."""
    cases: list[tuple[str, list[str]]] = []
    q = "MATCH (e:Entity) WHERE e.participant = $participant RETURN count(e) AS n"
    for name, value in BAD_PARAMS:
        cases.append((f"query -p {name} {value[:20]}", ["query", bank, "RETURN $x AS x", "-p", name, value,
                                                       "--participant", "P09"]))
        cases.append((f"run -p {name} {value[:20]}", ["run", bank, "object_history", "-p", name, value,
                                                     "-p", "object", "plate", "-p", "video", "P09_01"]))
    bad_ids = ("", " ", "P9", "p09", "P099", "../P09", "P09;", "*", "\u0000", "P09,,x")
    for value in (*bad_ids, "P11", "all", "P09,P37"):  # the last three: no one id, or not in this bank
        cases.append((f"query --participant {value!r}", ["query", bank, q, "--participant", value]))
        cases.append((f"stats --participant {value!r}", ["stats", bank, "--participant", value]))
        cases.append((f"tool --participant {value!r}", ["tool", bank, "search", "plate", "--participant", value]))
    for value in (*bad_ids, ","):
        cases.append((f"index --participants {value!r}", ["index", bank, "--fts", "--participants", value]))
        cases.append((f"build --participants {value!r}", ["build", f"{scratch}/never", "--participants", value,
                                                          "--quiet"]))
    cases.append(("index --participants P11", ["index", bank, "--fts", "--participants", "P11"]))
    cases += [
        ("query conflicting participants", ["query", bank, q, "-p", "participant", "P37", "--participant", "P09"]),
        ("query --write without participant", ["query", bank, "CREATE (:Participant {id: 'X'})", "--write"]),
        ("query param given twice", ["query", bank, q, "-p", "participant", "P09", "-p", "participant", "P09"]),
        ("query unused param", ["query", bank, "RETURN 1 AS a", "-p", "y", "1", "--participant", "P09"]),
        ("query missing param", ["query", bank, "RETURN $y AS a", "--participant", "P09"]),
        ("query empty", ["query", bank, ""]),
        ("query only a comment", ["query", bank, "// nothing"]),
        ("query syntax error", ["query", bank, "MATCH (x) RETRUN x", "--participant", "P09"]),
        ("query unknown table", ["query", bank, "MATCH (x:Nope) RETURN x", "--participant", "P09"]),
        ("query huge", ["query", bank, "RETURN '" + "x" * 40000 + "' AS a"]),
        ("query deep", ["query", bank, "RETURN " + "(" * 5000 + "1" + ")" * 5000]),
        ("query nested CASE", ["query", bank, "RETURN " + "CASE WHEN true THEN " * 25 + "1" + " END" * 25]),
        ("query timeout 0", ["query", bank, "RETURN 1 AS a", "--timeout", "0"]),
        ("query timeout nan", ["query", bank, "RETURN 1 AS a", "--timeout", "nan"]),
        ("query timeout text", ["query", bank, "RETURN 1 AS a", "--timeout", "soon"]),
        ("run unknown query", ["run", bank, "no_such_query"]),
        ("run missing param", ["run", bank, "object_history", "-p", "participant", "P09"]),
        ("run unknown param", ["run", bank, "videos", "-p", "participant", "P09", "-p", "nope", "1"]),
        ("tool unknown", ["tool", bank, "no_such_tool", "x", "--participant", "P09"]),
        ("tool time Infinity", ["tool", bank, "get_state_at_time", "Infinity", "--participant", "P09", "--arg", "video",
                                "P09_104"]),
        ("tool time NaN", ["tool", bank, "get_state_at_time", "NaN", "--participant", "P09", "--arg", "video",
                           "P09_104"]),
        ("tool time -Infinity", ["tool", bank, "get_state_at_time", "-Infinity", "--participant", "P09"]),
        ("tool time negative", ["tool", bank, "get_state_at_time", "--participant", "P09", "--arg", "time_seconds",
                                "-5", "--arg", "video", "P09_104"]),
        ("tool time 1e400", ["tool", bank, "get_state_at_time", "1e400", "--participant", "P09", "--arg", "video",
                             "P09_104"]),
        ("tool time a list", ["tool", bank, "get_state_at_time", "[1]", "--participant", "P09"]),
        ("tool window Infinity", ["tool", bank, "get_state_at_time", "10", "--participant", "P09", "--arg", "video",
                                  "P09_104", "--arg", "window", "Infinity"]),
        ("tool unknown video", ["tool", bank, "get_state_at_time", "10", "--participant", "P09", "--arg", "video",
                                "P99_999"]),
        ("tool top_k 0", ["tool", bank, "search_objects", "plate", "--participant", "P09", "--arg", "top_k", "0"]),
        ("tool top_k text", ["tool", bank, "search_objects", "plate", "--participant", "P09", "--arg", "top_k", "x"]),
        ("tool top_k nested", ["tool", bank, "search_objects", "plate", "--participant", "P09", "--arg", "top_k",
                               "[" * 100000]),
        ("tool unknown arg", ["tool", bank, "search_objects", "plate", "--participant", "P09", "--arg", "nope", "1"]),
        ("tool query nested", ["tool", bank, "get_state_at_time", "--participant", "P09", "--arg", "time_seconds",
                               "[" * 100000]),
        ("build empty bank path", ["build", "", "--participants", "P09", "--quiet"]),
        ("build blank bank path", ["build", "  ", "--participants", "P09", "--quiet"]),
        ("build under a file", ["build", f"{scratch}/afile/bank", "--participants", "P09", "--quiet"]),
        ("build in /proc", ["build", "/proc/memora-bank", "--participants", "P09", "--quiet"]),
        ("build annotations /etc/passwd", ["build", f"{scratch}/never", "--annotations", "/etc/passwd", "--quiet"]),
        ("build annotations binary", ["build", f"{scratch}/never", "--annotations", "/bin/sh", "--quiet"]),
        ("build annotations empty", ["build", f"{scratch}/never", "--annotations", f"{scratch}/afile", "--quiet"]),
        ("build unknown participant", ["build", f"{scratch}/never", "--participants", "P99", "--quiet"]),
        ("perf build empty participants", ["perf", "build", "--participants", ","]),
    ]
    for path in ("", "/nonexistent", "/etc", "/etc/passwd", f"{scratch}/afile", f"{scratch}/empty", f"{scratch}/orphan",
                 *(f"{scratch}/damaged-{n}" for n in BAD_MANIFESTS)):
        cases += [
            (f"stats {path}", ["stats", path]),
            (f"query {path}", ["query", path, "RETURN 1 AS a"]),
            (f"run {path}", ["run", path, "videos"]),
            (f"tool {path}", ["tool", path, "search", "plate", "--participant", "P09"]),
            (f"index {path}", ["index", path, "--fts"]),
        ]
        if path.startswith(f"{scratch}/damaged-"):
            cases.append((f"build into {path}", ["build", path, "--participants", "P09", "--quiet"]))
    return cases

"""The read guard: what ad-hoc Cypher (`memora query`, and any tool that takes Cypher from a
person or a model) may send to Kùzu, decided before anything reaches it.

Kùzu 0.11.3 opened read-only still runs COPY ... TO (overwrites any file), EXPORT DATABASE,
LOAD FROM (reads any file), ATTACH / USE (another participant's memory), LOAD EXTENSION (native
code) and CHECKPOINT, and a string of several statements crashes it (segmentation fault). So the
guard tokenizes the text the way Kùzu's lexer does (string literals with their escapes,
backtick names, // and /* */ comments) and accepts exactly one statement:

- read (`check_read_query`): it starts with MATCH, OPTIONAL MATCH, UNWIND, WITH, RETURN or CALL
  (optionally after EXPLAIN / PROFILE); no bare word of a data-write, file, extension, database,
  schema or transaction clause appears anywhere in it; every CALL names a read-only procedure
  (READ_PROCEDURES).
- write (`check_write_query`): the same, plus the data writes CREATE (of a pattern), MERGE, SET,
  DELETE, DETACH DELETE and REMOVE; never files, extensions, other databases or the schema.

A forbidden word inside a string literal, a comment or backticks is text, not a clause, and so
is one used as a property name (`e.set`), an alias (`AS copy`) or a map key (`{set: 1}`); any
other name that is such a word must be quoted in backticks. `AS` itself as an alias (`AS AS`) is
refused: Kùzu accepts it, and the word after it would otherwise pass as a name (`UNWIND [1] AS
AS LOAD FROM ...` read any file). The guard is the first, explaining line only: the query child
is confined by the kernel as well (memora_graph/confine.py), so what it misjudges still cannot
open a file outside the one database. Where the guard and Kùzu's lexer
could disagree about where a literal or comment ends (an unknown escape, an unterminated
comment, a character outside ASCII), the text is refused rather than guessed at. Bounds on size
and nesting keep out texts on which Kùzu's parser crashes or runs for minutes (5,000 nested
parentheses crash it; 20 nested CASE take 20 s to parse).

The tokenizer is written by hand: no Python package parses Kùzu's Cypher dialect, and the
guard needs only Kùzu's lexical rules (its ANTLR grammar's StringLiteral, EscapedChar,
EscapedSymbolicName and Comment), not a parser.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

from memora_graph.errors import QueryRefused

MAX_CHARS = 32_768
MAX_TOKENS = 4_096
MAX_DEPTH = 32  # nested ( [ {
MAX_CASE_DEPTH = 8  # nested CASE ... END: Kùzu's parse time doubles with each level
MAX_PARAM_DEPTH = 8  # nested lists / maps in a parameter value
INT64 = (-(2**63), 2**63 - 1)

# Read-only procedures a CALL may name (Kùzu 0.11.3, checked on a temporary database).
READ_PROCEDURES = frozenset({
    "SHOW_TABLES", "TABLE_INFO", "SHOW_CONNECTION", "SHOW_INDEXES", "SHOW_FUNCTIONS", "SHOW_SEQUENCES",
    "SHOW_WARNINGS", "SHOW_LOADED_EXTENSIONS", "SHOW_OFFICIAL_EXTENSIONS", "SHOW_ATTACHED_DATABASES",
    "SHOW_PROJECTED_GRAPHS", "DB_VERSION", "CATALOG_VERSION", "CURRENT_SETTING", "STATS_INFO", "STORAGE_INFO",
    "QUERY_FTS_INDEX", "QUERY_VECTOR_INDEX",
})
_PROCEDURE_WHY = {
    **dict.fromkeys(("CREATE_FTS_INDEX", "DROP_FTS_INDEX", "CREATE_VECTOR_INDEX", "DROP_VECTOR_INDEX"),
                    "creates or drops an index (a schema write)"),
    **dict.fromkeys(("READ_CSV_SERIAL", "READ_CSV_PARALLEL", "READ_PARQUET", "READ_NPY", "JSON_SCAN", "FILE_INFO"),
                    "reads files"),
    "READ_PANDAS": "reads Python objects of the calling process",
    **dict.fromkeys(("PROJECT_GRAPH", "PROJECT_GRAPH_CYPHER", "DROP_PROJECTED_GRAPH", "CLEAR_WARNINGS",
                     "_CACHE_ARRAY_COLUMN_LOCALLY"), "changes the state of the database connection"),
}

_READ_ONLY = "memora query is read-only (--write allows data writes to one participant, never files)"
_NEVER = "memora query never does this, not even with --write"
# The refusals speak to a person at the command line; an agent calling the MCP `cypher` tool has no
# `memora query` and no --write, so `for_agents` says the same in its terms.
_FOR_AGENTS = (
    (_READ_ONLY, "this tool only reads; nothing served can change the memory"),
    (_NEVER, "this is never allowed"),
    ("every memora query runs as one statement in a transaction of its own",
     "each call runs one statement in a transaction of its own"),
    ("memora query runs exactly one", "a call runs exactly one"),
    ("the read-only procedures memora query allows", "the read-only procedures allowed here"),
    ("(pass long lists as a parameter: -p NAME VALUE)", "(pass long lists in `params`)"),
)


def for_agents(message: str) -> str:
    """A refusal in the words of a tool call rather than of `memora query` (no --write, no -p)."""
    for cli, agent in _FOR_AGENTS:
        message = message.replace(cli, agent)
    return message


_DATA_WRITES = frozenset({"CREATE", "MERGE", "SET", "DELETE", "REMOVE"})
# Bare words refused anywhere in a statement (except as a name, see _is_name), with the reason.
_FORBIDDEN = {
    "COPY": "COPY reads and writes files (COPY ... TO overwrites any file)",
    "EXPORT": "EXPORT DATABASE writes a copy of the database to disk",
    "IMPORT": "IMPORT DATABASE loads files into the database",
    "LOAD": "LOAD FROM reads any file on disk and LOAD EXTENSION runs native code",
    "INSTALL": "INSTALL installs an extension (native code)",
    "UNINSTALL": "UNINSTALL removes an extension",
    "ATTACH": "ATTACH opens another database (such as another participant's memory)",
    "DETACH": "DETACH closes an attached database",
    "USE": "USE switches to an attached database (such as another participant's memory)",
    "CHECKPOINT": "CHECKPOINT writes the database files",
    "DROP": "DROP changes the schema",
    "ALTER": "ALTER changes the schema",
    "BEGIN": "BEGIN starts a transaction",
    "COMMIT": "COMMIT ends a transaction",
    "ROLLBACK": "ROLLBACK ends a transaction",
    "COMMIT_SKIP_CHECKPOINT": "COMMIT_SKIP_CHECKPOINT ends a transaction",
    "ROLLBACK_SKIP_CHECKPOINT": "ROLLBACK_SKIP_CHECKPOINT ends a transaction",
    "UPDATE": "UPDATE updates an extension (native code)",
    "FORCE": "FORCE INSTALL installs an extension (native code)",
}
# Refused at the start of a statement, or followed by ON (`comment` alone is a column of show_tables).
_STARTERS = {
    "COMMENT": "COMMENT ON changes the schema",
}
_SCHEMA = frozenset({"DROP", "ALTER", "COMMENT"})
_TRANSACTION = frozenset({"BEGIN", "COMMIT", "ROLLBACK", "COMMIT_SKIP_CHECKPOINT", "ROLLBACK_SKIP_CHECKPOINT"})
_READ_START = ("MATCH", "OPTIONAL", "UNWIND", "WITH", "RETURN", "CALL")
_WRITE_START = _READ_START + ("CREATE", "MERGE")
_CLAUSES = frozenset({"MATCH", "OPTIONAL", "UNWIND", "WITH", "RETURN", "CALL", "UNION", "CREATE", "MERGE", "SET",
                      "DELETE", "REMOVE"})

_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_NUMBER = re.compile(r"[0-9]+(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?")
_PARAM = re.compile(r"\$(?:[A-Za-z_][A-Za-z0-9_]*|[0-9]+)")
# Kùzu's Comment rule: '/*' ( ~'*' | '*' ~'/' )* '*/'. A '*' followed by '*' is consumed as a
# pair, so `/* **/ x */` is one comment and `/***/` none: ending at the first '*/' would be wrong.
_BLOCK_COMMENT = re.compile(r"/\*(?:[^*]|\*[^/])*\*/", re.S)
_ESCAPES = set("\\'\"bBfFnNrRtT")
_HEX4 = re.compile(r"[0-9A-Fa-f]{4}")


@dataclass(frozen=True)
class Token:
    kind: str  # word, name (`backticks`), string, number, param, punct, semicolon
    text: str
    start: int  # offset in the query text

    @property
    def upper(self) -> str:
        """A bare word in upper case (Kùzu's keywords are case-insensitive); '' for anything else."""
        return self.text.upper() if self.kind == "word" else ""


@dataclass(frozen=True)
class Statement:
    """One statement the guard accepted."""

    text: str  # what to send to Kùzu: the statement, without a trailing semicolon or comment
    mode: str  # "read" or "write"
    clauses: tuple[str, ...]  # its clause keywords in order of first use (MATCH, RETURN, ...)
    procedures: tuple[str, ...]  # the procedures it CALLs, upper case
    params: tuple[str, ...]  # the $parameters it uses

    @property
    def writes(self) -> bool:
        return any(c in _DATA_WRITES for c in self.clauses)


def _where(text: str, offset: int) -> str:
    line = text.count("\n", 0, offset) + 1
    col = offset - (text.rfind("\n", 0, offset) + 1) + 1
    return f"line {line}, column {col}"


def _refuse(text: str, offset: int, why: str) -> QueryRefused:
    return QueryRefused(f"refused ({_where(text, offset)}): {why}")


def tokenize(text: str) -> list[Token]:
    """Kùzu's tokens of `text`, comments dropped. Raises QueryRefused where the guard cannot be
    sure to split the text as Kùzu would."""
    out: list[Token] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c in " \t\r\n":
            i += 1
        elif text.startswith("//", i):
            end = text.find("\n", i)
            body = text[i:n if end < 0 else end]
            # Kùzu: '//' ~[\n\r]* '\r'? ( '\n' | EOF ); a lone '\r' inside is no comment there
            if "\r" in body[:-1]:
                raise _refuse(text, i, "a carriage return inside a // comment (end the line with \\n)")
            i = n if end < 0 else end + 1
        elif text.startswith("/*", i):
            m = _BLOCK_COMMENT.match(text, i)
            if not m:
                raise _refuse(text, i, "a /* comment that does not end with */ as Kùzu reads it")
            i = m.end()
        elif c in "'\"":
            j = i + 1
            while True:
                if j >= n:
                    raise _refuse(text, i, "a string literal that is never closed")
                d = text[j]
                if d == c:
                    break
                if d == "\\":
                    e = text[j + 1:j + 2]
                    if e in _ESCAPES and e:
                        j += 2
                    elif e in ("u", "U") and _HEX4.match(text, j + 2):
                        j += 6
                    else:
                        raise _refuse(text, j, f"the escape \\{e} in a string literal (Kùzu reads \\\\, \\', \\\", "
                                               "\\b, \\f, \\n, \\r, \\t and \\uXXXX)")
                else:
                    j += 1
            out.append(Token("string", text[i:j + 1], i))
            i = j + 1
        elif c == "`":
            j = i
            while j < n and text[j] == "`":  # Kùzu: ( '`' ~'`'* '`' )+ is one name
                close = text.find("`", j + 1)
                if close < 0:
                    raise _refuse(text, j, "a `name` that is never closed")
                j = close + 1
            out.append(Token("name", text[i:j], i))
            i = j
        elif m := _WORD.match(text, i):
            out.append(Token("word", m.group(), i))
            i = m.end()
        elif m := _NUMBER.match(text, i):
            out.append(Token("number", m.group(), i))
            i = m.end()
        elif m := _PARAM.match(text, i):
            out.append(Token("param", m.group(), i))
            i = m.end()
        elif c == ";":
            out.append(Token("semicolon", c, i))
            i += 1
        elif " " < c < "\x7f":
            out.append(Token("punct", c, i))
            i += 1
        else:
            what = f"the character U+{ord(c):04X}"
            raise _refuse(text, i, f"{what} outside a string literal (write names outside ASCII in `backticks`)")
        if len(out) > MAX_TOKENS:
            raise QueryRefused(f"refused: more than {MAX_TOKENS} tokens (pass long lists as a parameter: -p NAME VALUE)")
    return out


def _is_name(tokens: list[Token], i: int) -> bool:
    """Whether the bare word at `i` is used as a name, where no clause can start: a property
    (`e.set`), an alias (`AS copy`) or a map key (`{set: 1}`)."""
    prev = tokens[i - 1] if i > 0 else None
    before = tokens[i - 2] if i > 1 else None
    nxt = tokens[i + 1] if i + 1 < len(tokens) else None
    if prev and prev.text == "." and before and before.kind in ("word", "name"):
        return True
    if prev and prev.upper == "AS" and prev.kind == "word" and not _is_name(tokens, i - 1):
        return True  # an alias: AS's own word is a clause word, never an alias itself (AS AS is refused)
    return bool(prev and prev.text in ("{", ",") and nxt and nxt.text == ":")


def _as_name(t: Token, i: int, first: int) -> str:
    """A hint, for a refused word that is not the statement's first: it may be meant as a name."""
    return "" if i == first else f" (if {t.text} is a name here, quote it: `{t.text}`)"


def _forbidden_why(word: str, mode: str) -> str:
    why = _FORBIDDEN.get(word) or _STARTERS[word]
    if word in _TRANSACTION:
        return f"{why}; every memora query runs as one statement in a transaction of its own"
    if word in _SCHEMA:
        return f"{why}; {_NEVER}"
    return f"{why}; {_READ_ONLY if mode == 'read' else _NEVER}"


def check_query(text: object, write: bool = False) -> Statement:
    """Accept exactly one statement that only reads (or, with `write`, writes data), or raise
    QueryRefused naming the clause refused and why."""
    mode = "write" if write else "read"
    if not isinstance(text, str):
        raise QueryRefused(f"refused: a query is text, not {type(text).__name__}")
    if len(text) > MAX_CHARS:
        raise QueryRefused(f"refused: the query is {len(text)} characters long; at most {MAX_CHARS} "
                           "(pass long lists as a parameter: -p NAME VALUE)")
    tokens = tokenize(text)
    if tokens and tokens[-1].kind == "semicolon":
        tokens = tokens[:-1]
    for t in tokens:
        if t.kind == "semicolon":
            raise _refuse(text, t.start, "more than one statement; memora query runs exactly one (Kùzu 0.11.3 "
                                         "crashes on a string of several statements)")
    if not tokens:
        raise QueryRefused("refused: the query is empty")
    first = 1 if tokens[0].upper in ("EXPLAIN", "PROFILE") else 0
    if first >= len(tokens):
        raise _refuse(text, tokens[0].start, f"{tokens[0].upper} of nothing")
    lead = tokens[first]
    starts = _WRITE_START if write else _READ_START
    if lead.upper not in starts:
        if lead.upper in _FORBIDDEN or lead.upper in _STARTERS:
            raise _refuse(text, lead.start, _forbidden_why(lead.upper, mode))
        if lead.upper in _DATA_WRITES:
            raise _refuse(text, lead.start, f"{lead.upper} writes data; {_READ_ONLY}")
        kinds = ", ".join(starts[:-1]) + " or " + starts[-1]
        raise _refuse(text, lead.start, f"a {'query' if write else 'read query'} starts with {kinds}, "
                                        f"not {lead.text!r}")

    clauses: list[str] = []
    procedures: list[str] = []
    params: list[str] = []
    depth = case_depth = 0
    for i, t in enumerate(tokens):
        if t.kind == "param":
            params.append(t.text[1:])
            continue
        if t.kind == "punct":
            if t.text in "([{":
                depth += 1
                if depth > MAX_DEPTH:
                    raise _refuse(text, t.start, f"nested more than {MAX_DEPTH} levels deep (Kùzu's parser crashes "
                                                 "on deep nesting)")
            elif t.text in ")]}":
                depth = max(depth - 1, 0)
            continue
        word = t.upper
        if word == "AS" and t.kind == "word" and i > 0 and tokens[i - 1].upper == "AS":
            raise _refuse(text, t.start, "AS as a name: write it in backticks (`AS`), so that no clause can hide "
                                         "behind it")
        if not word or _is_name(tokens, i):
            continue
        nxt = tokens[i + 1] if i + 1 < len(tokens) else None
        if word == "CASE":
            case_depth += 1
            if case_depth > MAX_CASE_DEPTH:
                raise _refuse(text, t.start, f"more than {MAX_CASE_DEPTH} nested CASE expressions (Kùzu's parse time "
                                             "doubles with each level)")
        elif word == "END":
            case_depth = max(case_depth - 1, 0)
        elif word == "DETACH" and nxt is not None and nxt.upper == "DELETE":
            if not write:  # DETACH DELETE: a data write
                raise _refuse(text, t.start, f"DETACH DELETE writes data; {_READ_ONLY}")
        elif word in _FORBIDDEN or (word in _STARTERS and nxt is not None and nxt.upper == "ON"):
            raise _refuse(text, t.start, _forbidden_why(word, mode) + _as_name(t, i, first))
        elif word in _DATA_WRITES:
            if not write:
                raise _refuse(text, t.start, f"{word} writes data; {_READ_ONLY}" + _as_name(t, i, first))
            prev = tokens[i - 1] if i > 0 else None
            on_create = word == "CREATE" and prev is not None and prev.upper == "ON"  # MERGE ... ON CREATE SET
            if word in ("CREATE", "MERGE") and not on_create and (nxt is None or nxt.text != "("):
                what = f"{word} {nxt.text}" if nxt is not None else word
                raise _refuse(text, t.start, f"{what} changes the schema (tables, macros, sequences, types); "
                                             f"{_NEVER} (--write allows {word} of a pattern: {word} (n:Label ...))")
        elif word == "CALL":
            procedures.append(_check_call(text, tokens, i))
        if word in _CLAUSES and word not in clauses:
            clauses.append(word)
    body = tokens[-1]
    end = body.start + len(body.text)
    return Statement(text=text[:end], mode=mode, clauses=tuple(clauses), procedures=tuple(procedures),
                     params=tuple(dict.fromkeys(params)))


def _check_call(text: str, tokens: list[Token], i: int) -> str:
    call = tokens[i]
    name = tokens[i + 1] if i + 1 < len(tokens) else None
    after = tokens[i + 2] if i + 2 < len(tokens) else None
    if name is None or name.kind not in ("word", "name"):
        if name is not None and name.text == "{":
            raise _refuse(text, call.start, "CALL { ... } subqueries are not supported")
        raise _refuse(text, call.start, "CALL must name a procedure: CALL show_tables() RETURN *")
    proc = (name.text.strip("`") if name.kind == "name" else name.text).upper()
    if after is not None and after.text == "=":
        raise _refuse(text, call.start, f"CALL {name.text} = ... changes a setting of the database connection; "
                                        f"{_NEVER}")
    if proc not in READ_PROCEDURES:
        why = _PROCEDURE_WHY.get(proc, "is not one of the read-only procedures memora query allows")
        allowed = ", ".join(sorted(p.lower() for p in READ_PROCEDURES))
        raise _refuse(text, call.start, f"CALL {name.text} {why}; allowed: {allowed}")
    if after is None or after.text != "(":
        raise _refuse(text, call.start, f"CALL {name.text} must be followed by its arguments: CALL {name.text}(...)")
    return proc


def check_read_query(text: object) -> Statement:
    """One statement that only reads, or QueryRefused."""
    return check_query(text, write=False)


def check_write_query(text: object) -> Statement:
    """One statement that reads and writes data (never files, extensions, other databases or the
    schema), or QueryRefused."""
    return check_query(text, write=True)


# -- parameters -----------------------------------------------------------------------------------


def parse_param(name: object, raw: object) -> object:
    """A `-p NAME VALUE` value: JSON if it parses (numbers, lists, maps, true/false/null), else the
    string itself; refused where Kùzu could not bind it."""
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise QueryRefused(f"parameter name {name!r}: expected a name such as participant or object")
    if not isinstance(raw, str):
        return check_param(name, raw)
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    except RecursionError:
        raise QueryRefused(f"parameter {name}: the value is nested more than {MAX_PARAM_DEPTH} levels deep") from None
    return check_param(name, value)


def check_param(name: str, value: object, depth: int = 0) -> object:
    """`value` if Kùzu can bind it as $name: text, a number, true/false, null, or a non-empty list
    (items of one kind) or map of those, at most MAX_PARAM_DEPTH levels deep."""
    if depth > MAX_PARAM_DEPTH:
        raise QueryRefused(f"parameter {name}: the value is nested more than {MAX_PARAM_DEPTH} levels deep")
    if value is None or isinstance(value, (str, bool)):
        return value
    if isinstance(value, int):
        if not INT64[0] <= value <= INT64[1]:
            raise QueryRefused(f"parameter {name}: {value} does not fit a 64-bit integer")
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise QueryRefused(f"parameter {name}: {value} is not a finite number")
        return value
    if isinstance(value, list):
        if not value:
            raise QueryRefused(f"parameter {name}: an empty list has no item type Kùzu can bind; leave it out of "
                               "the query instead")
        kinds = {_kind(v) for v in value if v is not None}
        if len(kinds) > 1:
            raise QueryRefused(f"parameter {name}: a list's items must be of one kind, not "
                               f"{', '.join(sorted(kinds))}")
        return [check_param(name, v, depth + 1) for v in value]
    if isinstance(value, dict):
        if not value:
            raise QueryRefused(f"parameter {name}: an empty map has no type Kùzu can bind")
        for k in value:
            if not isinstance(k, str) or not k:
                raise QueryRefused(f"parameter {name}: map keys must be non-empty text")
        return {k: check_param(name, v, depth + 1) for k, v in value.items()}
    raise QueryRefused(f"parameter {name}: a {type(value).__name__} is not a value Kùzu can bind")


def _kind(value: object) -> str:
    if isinstance(value, bool):
        return "true/false"
    if isinstance(value, (int, float)):
        return "number"
    return {str: "text", list: "list", dict: "map"}.get(type(value), type(value).__name__)


def parse_params(pairs) -> dict:
    """`-p NAME VALUE` pairs as a dict of checked values; a name given twice is refused."""
    out: dict = {}
    for name, raw in pairs:
        if name in out:
            raise QueryRefused(f"parameter {name} is given twice")
        out[name] = parse_param(name, raw)
    return out


def check_participant(value: object, source: str = "participant") -> str:
    """A participant id (memora_graph/ids.py): refused if empty, not text, or not of that form."""
    from memora_graph.ids import RULE, describe, is_participant_id

    if not is_participant_id(value):
        raise QueryRefused(f"{source} must be one participant id ({RULE}), not {describe(value)}")
    return value

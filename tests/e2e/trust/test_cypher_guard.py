"""The read guard on its own: every attack of the corpus in every disguise is refused, before
anything reaches Kùzu; forbidden words inside literals, comments, backticks or names are not."""

from __future__ import annotations

import re
import string

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from memora_graph.cypher_guard import (
    MAX_CASE_DEPTH, MAX_DEPTH, check_param, check_read_query, check_write_query, parse_params, tokenize,
)
from memora_graph.errors import QueryRefused
from e2e.trust.corpus import ALLOWED, FORBIDDEN, NEVER, attacks

PATHS = {"{bank}": "/tmp/bank", "{other}": "/tmp/bank/P37.kuzu", "{out}": "/tmp/out"}


def fill(statement: str) -> str:
    for k, v in PATHS.items():
        statement = statement.replace(k, v)
    return statement


def escapes(check, corpus) -> list[str]:
    """The disguised statements `check` lets through."""
    out = []
    for _, disguise, statement in attacks(corpus):
        try:
            check(fill(statement))
        except QueryRefused as exc:
            assert str(exc).startswith("refused"), exc
        else:
            out.append(f"{disguise}: {statement}")
    return out


@pytest.mark.parametrize("kind,statement", FORBIDDEN)
def test_every_attack_in_every_disguise_is_refused_without_write(kind, statement):
    assert escapes(check_read_query, [(kind, statement)]) == []


@pytest.mark.parametrize("kind,statement", NEVER)
def test_write_mode_still_refuses_files_extensions_databases_schema(kind, statement):
    assert escapes(check_write_query, [(kind, statement)]) == []


@pytest.mark.parametrize("statement", [s for k, s in FORBIDDEN if k == "data"])
def test_write_mode_allows_data_writes(statement):
    assert check_write_query(statement).writes


@pytest.mark.parametrize("statement", ALLOWED)
def test_forbidden_words_in_literals_comments_and_names_pass(statement):
    s = check_read_query(fill(statement))
    assert s.mode == "read" and not s.writes


@pytest.mark.parametrize("statement,says", [
    ("COPY (RETURN 'x' AS a) TO 'b/manifest.json'", "COPY reads and writes files"),
    ("LOAD FROM '/etc/passwd' RETURN *", "LOAD FROM reads any file"),
    ("LOAD EXTENSION '/x.kuzu_extension'", "runs native code"),
    ("ATTACH 'b/P11.kuzu' AS o (dbtype kuzu)", "another participant's memory"),
    ("EXPORT DATABASE 'dir'", "writes a copy of the database"),
    ("CHECKPOINT", "CHECKPOINT writes the database files"),
    ("RETURN 1 AS a; RETURN 2 AS b", "more than one statement"),
    ("MATCH (e:Entity) SET e.name = 'x'", "SET writes data; memora query is read-only (--write allows data writes"),
    ("CALL threads=4", "changes a setting"),
    ("CALL create_fts_index('Entity', 'f', ['name'])", "a schema write"),
    ("BEGIN TRANSACTION", "transaction"),
])
def test_messages_say_which_clause_and_why(statement, says):
    with pytest.raises(QueryRefused) as exc:
        check_read_query(statement)
    assert says in str(exc.value) and "line 1, column" in str(exc.value)


def test_refusal_points_at_the_line_and_column():
    with pytest.raises(QueryRefused, match=r"line 3, column 3\): DELETE"):
        check_read_query("MATCH (e:Entity)\nWITH e\n  DELETE e")


def test_a_name_that_is_a_keyword_can_be_quoted():
    with pytest.raises(QueryRefused, match="quote it: `set`"):
        check_read_query("MATCH (set:Entity) RETURN set.name")
    assert check_read_query("MATCH (`set`:Entity) RETURN `set`.name")


def test_write_mode_refuses_schema_creation_but_not_on_create():
    with pytest.raises(QueryRefused, match="CREATE NODE changes the schema"):
        check_write_query("CREATE NODE TABLE X(id STRING PRIMARY KEY)")
    with pytest.raises(QueryRefused, match="CREATE MACRO changes the schema"):
        check_write_query("CREATE MACRO m(x) AS x")
    s = check_write_query("MERGE (p:Participant {id: 'P09'}) ON CREATE SET p.participant = 'P09'")
    assert s.clauses == ("MERGE", "CREATE", "SET")


def test_statement_is_cut_to_the_one_statement():
    s = check_read_query("  MATCH (e:Entity) RETURN e.name ; // trailing\n")
    assert s.text == "  MATCH (e:Entity) RETURN e.name"
    assert s.clauses == ("MATCH", "RETURN") and s.params == ()
    s = check_read_query("MATCH (e:Entity {participant: $participant}) WHERE e.name = $name RETURN e")
    assert s.params == ("participant", "name")


def test_procedures_are_reported_and_allowlisted():
    assert check_read_query("CALL show_tables() RETURN *").procedures == ("SHOW_TABLES",)
    assert check_read_query("CALL `table_info`('Entity') RETURN *").procedures == ("TABLE_INFO",)
    for bad in ("CALL show_tables RETURN *", "CALL { MATCH (n) RETURN n } RETURN 1", "CALL read_npy('x') RETURN *"):
        with pytest.raises(QueryRefused):
            check_read_query(bad)


@pytest.mark.parametrize("text,why", [
    ("", "empty"), ("   // nothing\n/* at all */", "empty"), ("EXPLAIN", "EXPLAIN of nothing"),
    ("RETURN 'open", "never closed"), ("RETURN `open", "never closed"), ("RETURN 1 /* open", "does not end"),
    ("RETURN 1 /***/ AS x", "does not end"),  # Kùzu reads no comment in /***/
    ("RETURN 'a\\q' AS x", "escape"), ("RETURN 'a\\u00' AS x", "escape"), ("RETURN 1 AS x // a\rb\n", "carriage return"),
    ("RETURN 1 AS é", "U+00E9"), ("RETURN\u00a01 AS x", "U+00A0"), ("RETURN 1 AS x\x00", "U+0000"),
    ("RETURN " + "(" * (MAX_DEPTH + 1) + "1" + ")" * (MAX_DEPTH + 1), "nested more than"),
    ("RETURN " + "CASE WHEN true THEN " * (MAX_CASE_DEPTH + 1) + "1" + " END" * (MAX_CASE_DEPTH + 1), "nested CASE"),
    ("RETURN " + "+".join(["1"] * 3000) + " AS x", "tokens"), ("RETURN '" + "x" * 40000 + "' AS x", "characters long"),
    ("SHOW TABLES", "starts with"), ("VACUUM", "starts with"), (None, "text"), (b"RETURN 1", "text"),
])
def test_texts_kuzu_might_read_differently_or_choke_on_are_refused(text, why):
    with pytest.raises(QueryRefused, match=re.escape(why)):
        check_read_query(text)


def test_tokenizer_follows_kuzu_lexical_rules():
    kinds = [(t.kind, t.text) for t in tokenize("RETURN 'a\\'b' AS `x``y`, \"q\\\"\" /* **/ x */ // c\n$p 1.5e3;")]
    assert kinds == [("word", "RETURN"), ("string", "'a\\'b'"), ("word", "AS"), ("name", "`x``y`"), ("punct", ","),
                     ("string", '"q\\""'), ("param", "$p"), ("number", "1.5e3"), ("semicolon", ";")]


# -- parameters ---------------------------------------------------------------------------------------


def test_parameter_values_are_checked():
    assert parse_params([("participant", "P09"), ("n", "3"), ("xs", '["a", "b"]'), ("s", "plain text")]) == {
        "participant": "P09", "n": 3, "xs": ["a", "b"], "s": "plain text"}
    for name, raw, says in [("x", "[" * 100000, "nested"), ("x", "[1, \"a\"]", "one kind"), ("x", "[]", "empty list"),
                            ("x", "{}", "empty map"), ("x", "99999999999999999999999999", "64-bit"),
                            ("x", "Infinity", "finite"), ("bad name", "1", "parameter name")]:
        with pytest.raises(QueryRefused, match=says):
            parse_params([(name, raw)])
    with pytest.raises(QueryRefused, match="given twice"):
        parse_params([("a", "1"), ("a", "2")])
    with pytest.raises(QueryRefused, match="nested"):
        check_param("x", [[[[[[[[[[[1]]]]]]]]]]])


# -- properties ---------------------------------------------------------------------------------------

KEYWORDS = sorted({"COPY", "EXPORT", "IMPORT", "LOAD", "INSTALL", "UNINSTALL", "ATTACH", "DETACH", "USE", "CHECKPOINT",
                   "DROP", "ALTER", "BEGIN", "COMMIT", "ROLLBACK", "CREATE", "MERGE", "SET", "DELETE", "REMOVE"})
SAFE_WORDS = ["MATCH", "RETURN", "WITH", "WHERE", "e", "n", "name", "Entity", "count", "LIMIT", "ORDER", "BY", "x"]


def _cased(word: str):
    return st.lists(st.booleans(), min_size=len(word), max_size=len(word)).map(
        lambda flips: "".join(c.lower() if f else c for c, f in zip(word, flips)))


# Text inside literals and comments: anything, forbidden words and quotes included.
_FREE = st.text(alphabet=string.printable, max_size=30) | st.sampled_from(
    [f"{k} ('x') TO '/etc/passwd'; " for k in KEYWORDS] + ["*/", "/*", "//", "'", '"', "`", "\\", ";"])


def _string_literal(text: str, quote: str) -> str:
    escaped = text.replace("\\", "\\\\").replace(quote, "\\" + quote).replace("\r", "\\r").replace("\n", "\\n")
    return quote + "".join(c if c.isprintable() or c == "\t" else " " for c in escaped) + quote


def _block_comment(text: str) -> str:
    return "/*" + text.replace("*", " ").replace("/", " ") + "*/"


def _line_comment(text: str) -> str:
    return "//" + text.replace("\n", " ").replace("\r", " ") + "\n"


_NOISE = st.one_of(
    st.sampled_from(SAFE_WORDS + ["(", ")", "=", "1", "2.5", "$p", "[", "]"]),
    st.builds(_string_literal, _FREE, st.sampled_from(["'", '"'])),
    st.builds(lambda t: "`" + t.replace("`", "") + "`", _FREE),
    st.builds(_block_comment, _FREE),
    st.builds(_line_comment, _FREE),
)
_SEP = st.sampled_from([" ", "\n", "\t", " /* c */ ", "\r\n"])


@st.composite
def statements_with_a_forbidden_clause(draw):
    """Noise tokens around one forbidden keyword that stands where a clause can start (not after
    '.', not after AS, not a map key)."""
    before = draw(st.lists(_NOISE, max_size=6))
    after = draw(st.lists(_NOISE, max_size=6))
    keyword = draw(st.sampled_from(KEYWORDS).flatmap(_cased))
    sep = draw(_SEP)
    return sep.join([draw(st.sampled_from(["MATCH (e)", "match (e:Entity)", "UNWIND [1] AS i", "RETURN 1 AS x"]))]
                    + before + [keyword] + after), keyword


@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(statements_with_a_forbidden_clause())
def test_no_statement_with_a_forbidden_clause_gets_past_the_read_guard(case):
    text, keyword = case
    with pytest.raises(QueryRefused) as exc:
        check_read_query(text)
    assert keyword.upper() in str(exc.value)  # refused for the clause, not for something else


@settings(max_examples=150, deadline=None)
@given(st.lists(st.one_of(st.builds(_string_literal, _FREE, st.sampled_from(["'", '"'])),
                          st.builds(_block_comment, _FREE), st.builds(_line_comment, _FREE)), max_size=5),
       st.sampled_from(["MATCH (e:Entity) WHERE e.name = {} RETURN e.name", "RETURN {} AS x"]))
def test_forbidden_words_in_literals_and_comments_never_cause_a_refusal(pieces, template):
    literal = next((p for p in pieces if p[0] in "'\""), "'x'")
    comments = " ".join(p for p in pieces if p[0] == "/")
    text = template.format(literal) + " " + comments
    assert check_read_query(text).text.startswith(template.split("{}")[0])


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=200))
def test_any_text_is_accepted_or_refused_never_an_exception(text):
    try:
        check_read_query(text)
    except QueryRefused:
        pass

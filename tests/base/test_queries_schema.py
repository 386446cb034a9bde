import re
from datetime import datetime

import pytest

from memora_graph import schema
from memora_graph.errors import QueryError, StoreError
from memora_graph.queries import load_queries, parse_query
from memora_graph.store import Store


@pytest.fixture()
def empty_store(tmp_path):
    store = Store(tmp_path / "P01.kuzu", read_only=False)
    store.apply_schema()
    store.ensure_indexes(fts=True, hnsw=True)  # FTS / HNSW indexes the retrieval queries read
    yield store
    store.close()


def _sample(field: str):
    """A value of the column's type in the schema (where a column of that name exists, or of its
    name after a prefix: `place_zones` is a Place's `zones`, `ev_turn` a StateEvent's `turn`), else text."""
    types = {c.name: c.type for t in schema.schema_tables().values() for c in t.columns}
    kind = types.get(field) or types.get(field.split("_", 1)[-1], "STRING")
    if kind.startswith("FLOAT["):
        return [0.0] * 384
    if kind.endswith("[]"):
        return ["sink"]
    return {"DOUBLE": 1.0, "INT64": 1, "BOOLEAN": True,
            "TIMESTAMP": datetime(2025, 1, 1)}.get(kind, "x")


def _dummy(param: str, cypher: str = ""):
    if param == "rows":  # one row with every field the query reads, matching no node
        return [{f: _sample(f) for f in sorted(set(re.findall(r"\br\.(\w+)", cypher)))}]
    if param in ("ids", "videos"):
        return ["nothing"]
    if param == "vector":
        return [0.0] * 384
    if param == "applied_at":
        return "2025-01-01 00:00:00"
    return "x"


def test_every_named_query_runs_on_an_empty_schema(empty_store):
    queries = load_queries()
    assert len(queries) >= 10
    for q in queries.values():
        if q.writes:
            continue
        empty_store.run(q, **{p: _dummy(p) for p in q.params})


def test_write_queries_prepare_in_a_rolled_back_transaction(empty_store):
    for q in load_queries().values():
        if q.writes:
            with pytest.raises(RuntimeError):
                with empty_store.transaction():
                    empty_store.run(q, **{p: _dummy(p, q.cypher) if p in ("rows", "ids", "participant", "vector", "applied_at")
                                          else _sample(p)
                                          for p in q.params})
                    raise RuntimeError("rollback")


def test_schema_is_applied_once_and_recorded(tmp_path):
    with Store(tmp_path / "a.kuzu", read_only=False) as s:
        first = s.apply_schema()
        assert first and s.apply_schema() == []
        assert s.migrations() == first


def test_loader_rejects_undeclared_and_unscoped_queries(tmp_path):
    bad = tmp_path / "bad.cypher"
    bad.write_text("// params: participant\nMATCH (e:Entity) WHERE e.participant = $participant AND e.name = $name RETURN e.id\n")
    with pytest.raises(QueryError, match="undeclared: name"):
        parse_query(bad)
    unscoped = tmp_path / "unscoped.cypher"
    unscoped.write_text("// params: name\nMATCH (e:Entity) WHERE e.name = $name RETURN e.id\n")
    with pytest.raises(QueryError, match="participant"):
        parse_query(unscoped)


def test_every_participant_query_takes_participant():
    for q in load_queries().values():
        if q.scope != "database":
            assert "participant" in q.params, q.name


def test_database_scope_queries_cannot_name_participant_tables(tmp_path):
    bad = tmp_path / "bad.cypher"
    bad.write_text("// scope: database\nMATCH (e:Entity) RETURN count(e)\n")
    with pytest.raises(QueryError, match="scope: database"):
        parse_query(bad)


def test_store_error_messages(tmp_path):
    with pytest.raises(StoreError, match="no database here"):
        Store(tmp_path / "missing.kuzu")
    junk = tmp_path / "junk.kuzu"
    junk.write_bytes(b"this is not a database" * 1000)
    with pytest.raises(StoreError, match="not a memora/Kùzu database"):
        Store(junk)
    empty = tmp_path / "empty.kuzu"
    empty.write_bytes(b"")
    with pytest.raises(StoreError, match="empty file"):
        Store(empty)
    with Store(tmp_path / "ok.kuzu", read_only=False) as s:
        s.apply_schema()
        with pytest.raises(StoreError, match="syntax error"):
            s.query("MATCH (x) RETRUN x")
    with Store(tmp_path / "ok.kuzu") as ro:
        with pytest.raises(StoreError, match="read-only"):
            ro.query("CREATE (:Participant {id: 'P01', participant: 'P01'})")


def test_a_refused_commit_leaves_no_transaction_open(empty_store, monkeypatch):
    """Kùzu checks some keys only at COMMIT (a duplicate the file's key index holds); a refused
    COMMIT must not leave its transaction open, or the next write on the connection fails too
    ("Write-write conflict": a live writer then lost the moments after the refused one)."""
    real = empty_store._execute

    def refuse_commit(cypher, params=None):
        if cypher == "COMMIT":
            raise StoreError("refused at COMMIT (injected)")
        return real(cypher, params)

    monkeypatch.setattr(empty_store, "_execute", refuse_commit)
    with pytest.raises(StoreError, match="injected"):
        with empty_store.transaction():
            empty_store.query("CREATE (v:Video {id: 'P01_01', participant: 'P01'})")
    monkeypatch.setattr(empty_store, "_execute", real)
    with empty_store.transaction():  # the connection writes again, and the refused row is not there
        empty_store.query("CREATE (v:Video {id: 'P01_02', participant: 'P01'})")
    assert empty_store.query("MATCH (v:Video) RETURN v.id AS id ORDER BY id")["id"].to_list() == ["P01_02"]

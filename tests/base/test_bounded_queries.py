"""Every named query a server (`query_*` tools) or the explorer offers is bounded by what it
returns (issue 36): it states a LIMIT its body ends with, or it reads one page keyed by a
parameter (a video, an object, a record). A new unbounded query fails here; the code that needs
every row reads a private `_..._all` twin, which no server offers."""

from __future__ import annotations

import pytest

from memora_graph.bank import Bank
from memora_graph.errors import QueryError
from memora_graph.queries import load_queries, parse_query
from memora_graph.serve import MemoryService

# the explorer writes one participant's whole memory into a static page (explore/__init__.py): its
# queries read everything by design and are not paged yet; any other unbounded one fails below
EXPLORER_WHOLE = {"_explore_videos", "_explore_segments", "_explore_places", "_explore_entities", "_explore_events",
                  "_explore_edits", "_explore_routines", "_explore_preferences", "_explore_evidence", "_tasks_all",
                  "_tool_inferred_links"}


def test_every_query_a_server_offers_is_paged_or_states_its_limit(small_bank):
    bank, _ = small_bank
    queries = load_queries()
    with MemoryService(bank) as service:
        offered = [e.name.removeprefix("query_") for e in service.endpoints() if e.kind == "query"]
    assert len(offered) > 10
    unbounded = [n for n in offered if not queries[n].bound]
    assert not unbounded, f"named queries a server offers without a stated bound: {unbounded}"
    for n in offered:
        q = queries[n]
        assert q.limit is not None or q.page in q.params, n
        assert q.limit is None or q.cypher.rstrip().upper().endswith(f"LIMIT {q.limit}"), n


def test_the_explorer_reads_no_other_unbounded_query(small_bank):
    import memora_graph.explore as explore

    queries = load_queries()
    with open(explore.__file__) as fh:
        text = fh.read()
    used = {n for n in queries if f'"{n}"' in text}
    assert used, "the explorer's queries are named in its module"
    assert {n for n in used if not queries[n].bound} <= EXPLORER_WHOLE


def test_a_stated_limit_must_be_the_querys_own(tmp_path):
    path = tmp_path / "q.cypher"
    path.write_text("// params: participant\n// bound: limit 10\nMATCH (e:Entity) WHERE e.participant = $participant "
                    "RETURN e.id LIMIT 20\n")
    with pytest.raises(QueryError, match="LIMIT 20"):
        parse_query(path)
    path.write_text("// params: participant\n// bound: page video\nMATCH (e:Entity) WHERE e.participant = $participant "
                    "RETURN e.id\n")
    with pytest.raises(QueryError, match="page key"):
        parse_query(path)


def test_bounded_queries_read_what_their_whole_twins_read_on_a_small_bank(small_bank):
    """On a memory under the limits, a bounded query returns what its `_all` twin does."""
    bank, _ = small_bank
    queries = load_queries()
    twins = [n for n in queries if n.startswith("_") and n.endswith("_all") and n[1:-4] in queries]
    assert len(twins) >= 8
    with Bank(bank).open("P37") as store:
        videos = [r["video"] for r in store.rows("videos", participant="P37")]
        for twin in twins:
            name = twin[1:-4]
            if queries[name].page == "video":
                got = [r for v in videos for r in store.rows(name, participant="P37", video=v)]
            else:
                got = store.rows(name, participant="P37")
            every = store.rows(twin, participant="P37")
            key = lambda r: repr(sorted(r.items()))  # noqa: E731 - pages come in another order
            assert sorted(map(key, got)) == sorted(map(key, every)), name

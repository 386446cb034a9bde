"""`memora serve --writable`: the MCP `remember` tool, reads that see it at once, a bearer token over
HTTP, background incremental consolidation; and `memora consolidate --incremental` equal to a
batch run. Real Kùzu in tmp dirs, the bundled MiniLM, the mcp SDK's client over loopback."""

from __future__ import annotations

import contextlib
import json
import shutil

import urllib.error
import urllib.request

import anyio
import pytest
from click.testing import CliRunner
from mcp import Client, MCPError
from mcp.client.streamable_http import create_mcp_http_client, streamable_http_client

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.consolidate.live import IncrementalConsolidation, consolidate_incremental, consolidation_cache
from memora_graph.consolidate.run import consolidate_participant
from memora_graph.errors import BankError, MemoraError
from memora_graph.form.live import LiveWriter, Moment
from memora_graph.integrity.verify import verify_bank
from memora_graph.serve import MemoryService
from memora_graph.cli.perf.serve import ServerProcess
from memora_graph.store import Store

from support.live import moments

TOKEN = "s3cret-token"


def test_remember_tool_in_process_and_reads_see_it(tmp_path):
    bank = tmp_path / "bank"
    service = MemoryService(bank, "P01", writable=True)
    try:
        assert "remember" in {e.name for e in service.endpoints()}
        before = service.call("search_objects", {"query": "kettle"})
        assert not service.call("get_object_history", {"object_query": "kettle"})["found"]  # (its names index made)
        got = service.call("remember", {"text": "put the kettle on the counter", "video": "kitchen-1", "start": 12.5,
                                        "end": 14.0})
        assert got["segment"] == "kitchen-1#t0000" and got["ops"][0]["op"] == "ADD"
        kettle = got["ops"][0]["entity"]
        after = service.call("search_objects", {"query": "kettle"})
        assert kettle not in json.dumps(before) and kettle in json.dumps(after)  # the next read sees it
        history = service.call("get_object_history", {"object_query": "kettle"})
        assert "kitchen-1" in json.dumps(history)
        acts = service.call("search_activities", {"query": "kettle counter"})
        assert "kitchen-1#t0000" in json.dumps(acts)
        again = service.call("remember", {"text": "put the kettle on the counter", "video": "kitchen-1", "start": 12.5})
        assert again["duplicate"] and again["ops"] == got["ops"]
        # the database is held open here, so no confined child could read it: no cypher tool by default
        assert "cypher" not in {e.name for e in service.endpoints()}
    finally:
        service.close()
    unconfined = MemoryService(bank, "P01", writable=True, unconfined_cypher=True)
    try:  # asked for explicitly, it reads in this process, guarded, and sees what was remembered
        rows = unconfined.call("cypher", {"query": "MATCH (s:Segment) WHERE s.participant = $participant "
                                                   "RETURN count(s) AS n"})
        assert rows["rows"] == [{"n": 1}]
        with pytest.raises(Exception, match="never allowed|refused|not allowed"):
            unconfined.call("cypher", {"query": "UNWIND [1] AS AS LOAD FROM '/etc/passwd' (file_format='csv', "
                                                "header=false, delim=':') RETURN *"})
    finally:
        unconfined.close()
    assert verify_bank(bank).ok
    with pytest.raises(BankError, match="one participant"):
        MemoryService(bank, None, writable=True)


def test_named_queries_of_a_writable_server_read_a_snapshot_without_the_readers_lock(tmp_path):
    """A writable server's named queries (`query_*`) run on a second connection to the writer's
    database: they see every acknowledged remember, and they run while the readers' lock is held
    (a remember committing, another tool reading), so a query scanning the memory for seconds
    holds up neither the writer nor the other tools."""
    import threading

    service = MemoryService(tmp_path / "bank", "P01", writable=True)
    try:
        for i, text in enumerate(["put the kettle on the counter", "open the fridge", "take the milk"]):
            service.call("remember", {"text": text, "video": "kitchen-1", "start": 2.0 * i})
        got = {}
        with service._lock:  # the readers' lock, as a remember holds it while it commits
            t = threading.Thread(target=lambda: got.update(service.call("query_baseline_segments", {"video": "kitchen-1"})), daemon=True)
            t.start()
            t.join(30)
            assert not t.is_alive(), "the named query waited for the readers' lock"
        assert got["row_count"] == 3 and {r["video"] for r in got["rows"]} == {"kitchen-1"}
        service.call("remember", {"text": "close the fridge", "video": "kitchen-1", "start": 9.0})
        assert service.call("query_baseline_segments", {"video": "kitchen-1"})["row_count"] == 4, "the next snapshot holds the new moment"
    finally:
        service.close()
    assert verify_bank(tmp_path / "bank").ok


def test_a_writable_servers_readers_leave_the_writer_a_core_and_freeze_what_a_first_ask_builds(tmp_path):
    """A writable server's readers (the tools' view, the named queries) run each Kùzu query on one
    thread, the writer on Kùzu's default, so that a remember committing while tools are called
    keeps a core (issue 36: a remember's p95 while streaming). What the first ask and plan of the
    view build joins what `warm` kept from the cyclic collector; closing gives it all back."""
    import gc

    threads = "CALL current_setting('threads') RETURN *"
    service = MemoryService(tmp_path / "bank", "P01", writable=True)
    try:
        for i, text in enumerate(["put the kettle on the counter", "open the fridge", "take the milk from the fridge"]):
            service.call("remember", {"text": text, "video": "kitchen-1", "start": 2.0 * i})
        service.call("query_baseline_segments", {"video": "kitchen-1"})  # opens the named queries' connection
        view = service._views["P01"]
        assert view.store._conn.execute(threads).get_all() == [["1"]]
        assert service._named_reader._conn.execute(threads).get_all() == [["1"]]
        assert service.writer.store._conn.execute(threads).get_all() != [["1"]]
        frozen = gc.get_freeze_count()
        assert frozen > 0, "warm froze what it loaded"

        def collectable(x) -> bool:  # in a generation the cyclic collector walks (not the frozen one)
            return any(o is x for o in gc.get_objects())

        kept = [[]]
        kept[0].append(kept)  # alive after the call, in a cycle, as what an ask builds on the view
        view.__dict__["_test_kept"] = kept
        assert collectable(kept)
        assert service.call("ask", {"question": "where is the milk?"})["answer"]
        assert gc.get_freeze_count() > frozen and not collectable(kept), "what the first ask left alive is frozen"
        assert service.call("plan", {"goal": "make tea"})
        after = gc.get_freeze_count()
        service.call("ask", {"question": "where is the kettle?"})
        # only a view's first ask and plan freeze again: a freeze would add what the call built; a frozen
        # object freed by its count (a cache entry replaced, a warnings registry cleared) leaves
        assert gc.get_freeze_count() <= after, "only a view's first ask and plan freeze again"
    finally:
        service.close()
    assert gc.get_freeze_count() == 0, "closing the last warm view gives every frozen object back"


def test_tools_answer_while_a_remember_commits(tmp_path, monkeypatch):
    """A writable server's readers read through a connection of their own (the last committed
    snapshot): a tool call made while a remember's transaction is open (held for a second here)
    answers before the commit, without the moment; the next call, after it, sees it."""
    import threading
    import time

    service = MemoryService(tmp_path / "bank", "P01", writable=True)
    try:
        service.call("remember", {"text": "put the kettle on the counter", "video": "kitchen-1", "start": 0.0})
        inside, release = threading.Event(), threading.Event()
        real = service.writer.store.transaction

        @contextlib.contextmanager
        def slow_transaction():
            with real():
                yield
                inside.set()
                release.wait(20)  # the statements ran; the commit waits

        monkeypatch.setattr(service.writer.store, "transaction", slow_transaction)
        done = {}
        t = threading.Thread(target=lambda: done.update(service.call(
            "remember", {"text": "take the knife from the drawer", "video": "kitchen-1", "start": 5.0})), daemon=True)
        t.start()
        assert inside.wait(20)
        t0 = time.perf_counter()
        during = service.call("search_objects", {"query": "knife"})
        history = service.call("get_object_history", {"object_query": "kettle"})
        waited = time.perf_counter() - t0
        release.set()
        t.join(20)
        assert waited < 5.0 and not t.is_alive() and done["segment"] == "kitchen-1#t0001"
        added = [op["entity"] for op in done["ops"] if op["op"] == "ADD"]
        assert added and "kitchen-1" in json.dumps(history) and added[0] not in json.dumps(during)
        assert added[0] in json.dumps(service.call("search_objects", {"query": "knife"}))
    finally:
        monkeypatch.undo()
        service.close()
    assert verify_bank(tmp_path / "bank").ok


def _client(url: str, token: str | None):
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    return Client(streamable_http_client(url, http_client=create_mcp_http_client(headers=headers)))


def test_remember_over_http_needs_the_token(tmp_path):
    bank = tmp_path / "bank"
    refused = CliRunner().invoke(main, ["serve", str(bank), "--participant", "P01", "--writable", "--transport", "http"])
    assert refused.exit_code == 2 and "--token" in refused.output
    server = ServerProcess(bank, "P01", "--writable", "--token", TOKEN)
    try:
        assert server.url.startswith("http://127.0.0.1:")  # loopback by default
        with pytest.raises(urllib.error.HTTPError) as refused_http:
            urllib.request.urlopen(urllib.request.Request(server.url, data=b"{}", method="POST"), timeout=60)
        assert refused_http.value.code == 401

        async def main_() -> None:
            async with _client(server.url, TOKEN) as client:
                tools = {t.name: t for t in (await client.list_tools()).tools}
                assert "remember" in tools and tools["remember"].annotations.read_only_hint is False
                res = await client.call_tool("remember", {"text": "#C C takes a knife from the drawer",
                                                          "video": "ego-1", "start": 3.0, "end": 4.0})
                assert not res.is_error, res.content
                ops = res.structured_content["ops"]
                assert {o["op"] for o in ops} == {"ADD"} and any(o["entity"] == "P01:knife" for o in ops)
                found = await client.call_tool("get_object_history", {"object_query": "knife"})
                assert "ego-1" in json.dumps(found.structured_content)
                with pytest.raises(MCPError, match="start"):  # invalid params, naming the field
                    await client.call_tool("remember", {"text": "open the fridge", "video": "ego-1", "start": -2})
                with pytest.raises(MCPError, match="start"):  # out of the stated range (24 h)
                    await client.call_tool("remember", {"text": "open the fridge", "video": "ego-1", "start": 1e308})

        anyio.run(main_)
    finally:
        server.stop()
    assert verify_bank(bank).ok


def _inferred(store: Store, p: str) -> dict:
    routines = store.query("MATCH (r:Routine) WHERE r.participant = $p RETURN r.id AS id, r.goal AS goal, "
                           "r.canonical_steps AS steps, r.count AS count, r.supporting_episodes AS ev ORDER BY id",
                           {"p": p}).to_dicts()
    prefs = store.query("MATCH (r:Preference) WHERE r.participant = $p RETURN r.id AS id, r.statement AS s, "
                        "r.count AS count, r.supporting_episodes AS ev ORDER BY id", {"p": p}).to_dicts()
    return {"routines": routines, "preferences": prefs}


def test_incremental_consolidation_equals_a_batch_run(tmp_path):
    """A stream of remembers with incremental consolidation after each batch gives the same
    routines and preferences as one full consolidation of the same memory."""
    from memora_graph.embed import get_embedder

    bank = tmp_path / "bank"
    # where the CLI keeps it, recorded in the bank's manifest as a server's consolidation records it
    state = IncrementalConsolidation(consolidation_cache(bank, "P01"), bank=Bank(bank), participant="P01")
    stream = [moments(40, video=f"day-{d}", offset=0.0) for d in range(3)]
    with LiveWriter(bank, "P01") as memory:
        for day in stream:
            for m in day:
                memory.remember(m)
            consolidate_incremental(memory.store, memory.store, "P01", memory.embedder, state)
        assert state.reused == 2 and state.recomputed == 1  # the last run: only the new video's pass
        live = _inferred(memory.store, "P01")
        consolidate_participant(memory.store, "P01", get_embedder())
        batch = _inferred(memory.store, "P01")
    assert live == batch and live["preferences"], live
    # the CLI: incremental runs record in the manifest, and verify still passes
    res = CliRunner().invoke(main, ["consolidate", str(bank), "--incremental", "--json"])
    assert res.exit_code == 0, res.output
    row = json.loads(res.output)[0]
    assert row["videos_recomputed"] == 0 and row["videos_reused"] == 3  # nothing new since
    assert Bank(bank).manifest()["participants"]["P01"]["consolidated"]
    assert verify_bank(bank).ok


def test_folds_too_large_to_be_worth_reading_back_are_not_kept(tmp_path, monkeypatch):
    """Reading the folds back from JSON costs more than recomputing when they are large (231 MB at
    100 h), so above CACHE_MAX_BYTES none are kept: the CLI says so, removes an older file, and its
    next run recomputes every video to the same records."""
    import memora_graph.consolidate.live as live

    bank = tmp_path / "bank"
    with LiveWriter(bank, "P01") as memory:
        for d in range(2):
            for m in moments(30, video=f"day-{d}", offset=0.0):
                memory.remember(m)
    run = lambda: json.loads(CliRunner().invoke(main, ["consolidate", str(bank), "--incremental", "--json"]).output)[0]
    first = run()
    cache = consolidation_cache(bank, "P01")
    assert first["folds_kept"] and cache.exists() and first["videos_recomputed"] == 2
    monkeypatch.setattr(live, "CACHE_MAX_BYTES", cache.stat().st_size - 1)
    with LiveWriter(bank, "P01") as memory:  # something new, so the folds change and are saved again
        memory.remember(Moment("day-1", 500.0, 503.0, "open the fridge"))
    second = run()
    assert second["folds_kept"] is False and not cache.exists()
    with LiveWriter(bank, "P01") as memory:
        incremental = _inferred(memory.store, "P01")
    third = run()
    assert third["videos_recomputed"] == 2 and third["videos_reused"] == 0
    with LiveWriter(bank, "P01") as memory:
        assert _inferred(memory.store, "P01") == incremental and incremental["preferences"]
    assert verify_bank(bank).ok


def _rows(k) -> dict:
    return {"routines": k.routines, "preferences": k.preferences, "supported_by": sorted(set(k.supported_by)),
            "uses": sorted(set(k.uses)), "about": sorted(set(k.about))}


def _batch(store: Store, p: str) -> dict:
    from memora_graph.consolidate.memory import load_memory
    from memora_graph.consolidate.run import deterministic_processors, infer

    ids = {r["id"] for r in store.fetch("_consolidate_entity_ids", participant=p)}
    return _rows(infer(load_memory(store, p), ids, deterministic_processors()))


def test_incremental_consolidation_equals_batch_at_every_point_with_merges(tmp_path):
    """Four videos written in turns (an old video continued later), an entity merged into another
    between two runs (re-identifying the steps of videos already folded), n-grams that start
    recurring in videos folded before: after each incremental run, the records (ids, statements,
    counts, evidence edges) equal a batch consolidation of the same memory; a state read back from
    its cache file goes on to the same records; only the changed videos are read again."""
    bank = tmp_path / "bank"
    state = IncrementalConsolidation(consolidation_cache(bank, "P01"))
    extra = ["take the cup", "put the cup on the counter", "wash the plate", "put the plate in the sink"]
    plan = [("day-0", moments(30, video="day-0")), ("day-1", moments(25, video="day-1")),
            ("day-0", [Moment("day-0", 200.0 + 4 * i, 203.0 + 4 * i, t) for i, t in enumerate(extra * 2)]),
            ("day-2", moments(30, video="day-2")), ("day-3", [Moment("day-3", 4.0 * i, 4.0 * i + 3, t)
                                                             for i, t in enumerate(reversed(extra * 3))])]
    with LiveWriter(bank, "P01") as memory:
        for step, (video, stream) in enumerate(plan):
            for m in stream:
                memory.remember(m)
            if step == 3:  # an editor's merge, written as the writer writes one (here the knife of every
                # earlier video is folded into the bread: what counts is that folded steps are re-identified)
                n = memory.store.query("MATCH (e:Entity {id: 'P01:knife'}), (k:Entity {id: 'P01:bread'}) "
                                       "SET e.status = 'merged', e.merged_into = k.id RETURN count(*) AS n").item()
                assert n == 1
            got = consolidate_incremental(memory.store, memory.store, "P01", memory.embedder, state)
            assert _rows(got) == _batch(memory.store, "P01"), f"after run {step}"
            assert state.recomputed == (1 if step != 3 else 3), (step, state.recomputed)  # 3: day-0, day-1 re-identified
            if step == 1:
                assert state.resequenced == 1  # day-0's n-grams now recur in day-1
            if step == 3:
                cited = {e for _, e in got.uses + got.about}
                assert "P01:bread" in cited and "P01:knife" not in cited
            state.save()
            again = IncrementalConsolidation(consolidation_cache(bank, "P01"))  # the CLI's next run
            assert _rows(again.infer(memory.store, "P01", {r["id"] for r in memory.store.fetch(
                "_consolidate_entity_ids", participant="P01")})) == _rows(got)
            assert again.recomputed == 0 and again.reused == len(state.folds)


def test_kept_folds_are_read_only_as_recorded_in_the_manifest(tmp_path):
    """The folds an incremental consolidation keeps (BANK/.cache/consolidate-PXX.json) feed the
    records it writes into the database: a file not as the bank's manifest recorded it when it was
    saved (edited, even into valid folds) is recomputed, never read."""
    bank = tmp_path / "bank"
    with LiveWriter(bank, "P01") as memory:
        for m in moments(30, video="day-0"):
            memory.remember(m)
        state = IncrementalConsolidation(consolidation_cache(bank, "P01"), bank=memory.bank, participant="P01")
        consolidate_incremental(memory.store, memory.store, "P01", memory.embedder, state)
        state.save()
        assert Bank(bank).manifest()["participants"]["P01"]["derived"]["consolidate"]["files"]["consolidate-P01.json"]
        kept = IncrementalConsolidation(consolidation_cache(bank, "P01"), bank=memory.bank, participant="P01")
        assert kept.folds and not kept.unsaved, "read back as recorded"
        path = consolidation_cache(bank, "P01")
        data = json.loads(path.read_text())
        data["merged"] = {"P01:cup": "P01:forged"}
        path.write_text(json.dumps(data))
        edited = IncrementalConsolidation(path, bank=memory.bank, participant="P01")
        assert not edited.folds and edited.unsaved, "the edited folds were read"
    report = verify_bank(bank)
    assert not report.ok and any("consolidate-P01.json: not as recorded" in line for line in report.rows[0]["problems"])


def test_background_consolidation_in_the_writable_server(tmp_path):
    bank = tmp_path / "bank"
    service = MemoryService(bank, "P01", writable=True, consolidate_every=25)
    try:
        assert service.call("get_preferences", {"query": "put the milk in the fridge"})["preferences"] == []
        for d in range(2):
            for m in moments(30, video=f"day-{d}"):
                service.call("remember", {"text": m.text, "video": m.video, "start": m.start, "end": m.end})
        assert service.consolidator.wait(300)
        assert service.consolidator.error is None and service.consolidator.runs
        prefs = service.call("get_preferences", {"query": "put the milk in the fridge"})["preferences"]
        assert prefs and "fridge" in json.dumps(prefs).lower()  # the new records, read after the swap
    finally:
        service.close()
    assert verify_bank(bank).ok


# -- a writable server reads the persisted tool stores ----------------------------------------------
P = "P37"
READS = [("search", {"query": "wash the pan"}), ("search", {"query": "milk fridge"}),
         ("search_objects", {"query": "knife", "top_k": 10}), ("search_objects", {"query": "milk"}),
         ("search_activities", {"query": "cut vegetables"}), ("search_activities", {"query": "pour milk into the cup"}),
         ("search_patterns", {"query": "after washing"}), ("get_routine_skill", {"goal_query": "wash pan"}),
         ("get_preferences", {"query": "knife"}), ("get_object_history", {"object_query": "knife"}),
         ("get_object_history", {"object_query": "fridge", "max_entries": 5}),
         ("get_object_history", {"object_query": "milk"}), ("get_object_history", {"object_query": "pan"}),
         ("search_environment", {"query": "sink"}), ("search_environment", {"query": "fridge"}),
         ("get_state_at_time", {"time_seconds": 30, "video": "P37_live"}),
         ("get_state_at_time", {"time_seconds": 1690, "video": "P37_101"}),
         ("get_state_at_time", {"time_seconds": 120, "video": "P37_102"}),
         ("get_video_activities", {"video": "P37_live"}), ("get_video_activities", {"video": "P37_101", "top_k": 50}),
         ("ask", {"question": "Where is the knife?"}), ("ask", {"question": "What did P37 do after opening the fridge?"})]
# a new video; an old one extended past its end (its objects' histories grow); places seen again
LIVE = moments(20, video="P37_live") + moments(6, video="P37_101", offset=1700.0)


def _reads(service: MemoryService) -> list[str]:
    out = []
    for name, args in READS:
        try:
            out.append(json.dumps(service.call(name, args), sort_keys=True))
        except MemoraError as exc:  # a video not remembered yet
            out.append(f"{type(exc).__name__}: {exc}")
    return out


@pytest.fixture()
def stored_bank(small_bank, tmp_path):
    import shutil

    from memora_graph.retrieve.view import persist_bank

    path = tmp_path / "bank"
    shutil.copytree(small_bank[0], path, ignore=shutil.ignore_patterns("tools-*"))
    persist_bank(path, [P])
    return path


def test_a_writable_server_reads_the_stores_and_answers_as_a_fresh_open(stored_bank):
    """The readers of `memora serve --writable` read the persisted tool stores written for the
    database as the writer opened it, and take remembered moments in through the overlay: after
    moments in a new video and in an old one (old objects' histories, places seen again), every
    tool answers as a read-only server opened afterwards on stores written again."""
    from memora_graph.retrieve.persist import store_dir

    bank = stored_bank
    meta = json.loads((store_dir(bank, P) / "meta.json").read_text())
    service = MemoryService(bank, P, writable=True)
    try:
        view = service._views[P]
        assert view._persisted is not None and view.persisted_written is None, "fresh stores, read as they are"
        assert meta["db_sha256"] == service.writer.opened_sha256
        before = _reads(service)
        touched = set()
        for m in LIVE:
            got = service.call("remember", {"text": m.text, "video": m.video, "start": m.start, "end": m.end})
            touched |= {op["entity"] for op in got["ops"]}
        assert view._persisted is not None, "still reading the stores (nothing found damaged)"
        assert "entities" in view.__dict__ and "entity" in view._vector_cache, "entities taken in, not read whole"
        old = [e for e in touched if e in view.history._row]
        assert old, "the moments extended histories the persisted index holds"
        live = _reads(service)
    finally:
        service.close()
    assert live != before
    assert verify_bank(bank).ok
    # the writer's close recorded the database's new sha256 and the journal of the moments leading
    # to it (form/live_journal.py): a reader opens the same stores and takes the moments in
    from memora_graph.retrieve.persist import PersistedStores

    stores = PersistedStores.open(bank, P, Bank(bank).checked_sha256(P), meta["embed_model"])
    assert stores.meta["db_sha256"] == meta["db_sha256"] and len(stores.journal) == len(LIVE)
    reader = MemoryService(bank, P)
    try:
        assert reader._views[P].persisted_written is None and reader._views[P].replayed[0] == len(LIVE)
        journaled = _reads(reader)
    finally:
        reader.close()
    assert live == journaled
    shutil.rmtree(store_dir(bank, P))  # and as a reader computing every store from the database
    reader = MemoryService(bank, P)
    try:
        assert reader._views[P].persisted_written is not None
        fresh = _reads(reader)
    finally:
        reader.close()
    assert live == fresh


def test_a_restarted_writer_never_reads_stores_older_than_its_database(stored_bank):
    """A writable server after another wrote (closed, so its sha256 was recorded) reads the
    stores of the database before, with the journal of what was remembered since; a writer
    killed before its close recorded the journal's end makes them stale: written again from
    the database. Either way it answers as a fresh open does."""
    from memora_graph.form.live_journal import RECORD

    bank = stored_bank
    with LiveWriter(bank, P) as memory:
        for m in moments(5, video="P37_live"):
            memory.remember(m)
    service = MemoryService(bank, P, writable=True)
    try:
        view = service._views[P]
        assert view._persisted is not None and view.persisted_written is None, "the stores and the journal"
        assert view.replayed[0] == 5
        got = _reads(service)
    finally:
        service.close()
    with MemoryService(bank, P, recipe="inprocess") as reader:
        assert got == _reads(reader)
    Bank(bank).derived.drop(P, RECORD)  # (as a killed writer leaves it: no journal leading to the database)
    service = MemoryService(bank, P, writable=True)
    try:
        view = service._views[P]
        assert view._persisted is not None and view.persisted_written is not None, "stale: written again"
        got = _reads(service)
    finally:
        service.close()
    with MemoryService(bank, P, recipe="inprocess") as reader:
        assert got == _reads(reader)


def test_perf_live_without_consolidation(stored_bank, tmp_path):
    """`memora perf live --no-consolidation` measures remember and the tools only, on a copy of the
    bank given (its stores read), and records the start, the stores read and the peak memory."""
    before = sorted(p.name for p in stored_bank.rglob("*"))
    got = CliRunner().invoke(main, ["perf", "live", "--participant", P, "--sizes", "1", "--bank", f"1={stored_bank}",
                                    "--work", str(tmp_path / "w"), "--remembers", "10", "--tool-rounds", "1",
                                    "--rate", "20", "--no-consolidation", "--json"])
    assert got.exit_code == 0, got.output
    row = json.loads(got.stdout)[0]
    assert row["tool_stores"] == "read" and row["remember_cpu_p50_ms"] > 0 and row["peak_rss_mb"] > 0
    assert "consolidate_per_100_s" not in row and "search_objects" in row["tool_idle_p95_by_tool_ms"]
    assert row["ask_idle_p95_ms"] == row["tool_idle_p95_by_tool_ms"]["ask"] and row["plan_stream_p95_ms"] > 0
    named = {n: v for n, v in row["tool_idle_p95_by_tool_ms"].items() if n.startswith("query_")}
    assert row["named_query_worst"] in named and row["named_query_worst_p95_ms"] >= max(named.values())
    assert sorted(p.name for p in stored_bank.rglob("*")) == before, "the given bank is never written"
    # after the remembers, both opens read the stores with the journal of what was remembered
    assert row["reopen_writable_stores"].startswith("read + ") and row["first_read_stores"].startswith("read + ")
    assert row["reopen_writable_s"] > 0 and row["first_read_first_ask_s"] > 0


def test_opens_after_remembers_append_to_the_journal_and_never_rewrite_the_stores(stored_bank, monkeypatch):
    """Batches of remembers (the CLI's writer, then a writable server's), each followed by a
    writable and a read-only open: the persisted stores' files are never written again (same
    bytes, same inode and change time); the journal only grows, by the moments remembered; and
    every open answers as one computing the stores from the database."""
    from memora_graph.form.live_journal import RECORD, journal_path
    from memora_graph.retrieve.persist import store_dir

    bank = stored_bank
    root = store_dir(bank, P)

    def files() -> dict:
        return {f.name: (f.stat().st_ino, f.stat().st_ctime_ns, f.read_bytes()) for f in root.iterdir()
                if f.name != "verified.json"}

    kept = files()
    sizes = []
    with LiveWriter(bank, P) as memory:  # `memora remember` (no server)
        for m in moments(4, video="P37_cli"):
            memory.remember(m)
    for batch in range(2):
        service = MemoryService(bank, P, writable=True)
        try:
            assert service._views[P].persisted_written is None and service._views[P].replayed[0] == 4 + 3 * batch
            for m in moments(3, video=f"P37_srv{batch}"):
                service.call("remember", {"text": m.text, "video": m.video, "start": m.start, "end": m.end})
        finally:
            service.close()
        sizes.append(journal_path(bank, P).stat().st_size)
        with MemoryService(bank, P) as reader:
            assert reader._views[P].persisted_written is None and reader._views[P].replayed[0] == 7 + 3 * batch
            journaled = _reads(reader)
        assert files() == kept, "the stores' files were not written again"
        monkeypatch.setenv("MEMORA_TOOL_STORES", "0")  # what Kùzu holds, read whole
        with MemoryService(bank, P) as fresh:
            assert fresh._views[P]._persisted is None
            assert journaled == _reads(fresh)
        monkeypatch.delenv("MEMORA_TOOL_STORES")
    assert sizes[0] < sizes[1] and Bank(bank).derived.get(P, RECORD)["n"] == 10
    assert verify_bank(bank).ok
    # a journal that is not as recorded (edited) is damaged: the stores are computed again, never
    # brought up to date with it
    path = journal_path(bank, P)
    path.write_bytes(path.read_bytes().replace(b"P37_srv1", b"P37_srvX", 1))
    with MemoryService(bank, P) as reader:
        assert reader._views[P].persisted_written is not None and "replayed" not in reader._views[P].__dict__
        assert _reads(reader) == journaled

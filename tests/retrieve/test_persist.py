"""The stores persisted next to a bank for one-shot tools: the same results as reading Kùzu,
Kùzu left closed when they suffice, and stale or damaged files detected, never used."""

from __future__ import annotations

import json
import logging
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.retrieve import MemoryView, call_tool
from memora_graph.retrieve.persist import PersistedStores, StaleStores, store_dir
from memora_graph.retrieve.view import persist_bank

P = "P37"
CALLS = [("search", {"query": "wash the pan"}), ("search_objects", {"query": "knife", "top_k": 10}),
         ("search_activities", {"query": "cut vegetables"}), ("search_patterns", {"query": "after washing"}),
         ("get_routine_skill", {"goal_query": "wash pan"}), ("get_preferences", {"query": "knife"}),
         ("get_object_history", {"object_query": "pan"}), ("search_environment", {"query": "sink"}),
         ("get_state_at_time", {"time_seconds": 120})]


@pytest.fixture()
def bank(small_bank, tmp_path):
    path = tmp_path / "bank"
    shutil.copytree(small_bank[0], path, ignore=shutil.ignore_patterns("tools-*"))
    return path


def _results(path, embedder, persist: bool) -> list[str]:
    with MemoryView.open(path, P, embedder, persist=persist) as view:
        view.encoder.clear()
        out = []
        for name, args in CALLS:
            if name == "get_state_at_time":
                args = {**args, "video": sorted(view.videos)[0]}
            out.append(json.dumps(call_tool(view, name, args).as_json(), sort_keys=True))
        return out


def _count_hashes(monkeypatch) -> list[str]:
    """The names of the store files hashed from now on, in order."""
    from memora_graph.retrieve import persist

    hashed: list[str] = []
    real = persist._sha256
    monkeypatch.setattr(persist, "_sha256", lambda path: hashed.append(path.name) or real(path))
    return hashed


def _flip_keeping_size_and_mtime(path, offset: int) -> None:
    """Flip one bit of `path` in place and put its access and modification times back: only the
    change time tells (a bit flipped under the file system would not even move that)."""
    import os

    st = path.stat()
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_persisted_stores_give_the_results_kuzu_gives(bank, embedder):
    reference = _results(bank, embedder, persist=False)
    assert not store_dir(bank, P).exists(), "persist=False writes nothing"
    written = persist_bank(bank, [P])
    assert written.written == [store_dir(bank, P)]
    meta = json.loads((store_dir(bank, P) / "meta.json").read_text())
    assert meta["db_sha256"] == Bank(bank).manifest()["participants"][P]["integrity"]["sha256"]
    assert {"vectors-segment.npy", "bm25-segment.json", "rows_tool_entities.json"} <= set(meta["files"])
    assert persist_bank(bank, [P]).written == [], "up-to-date stores are not written again"

    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is not None and view._store is None
        assert call_tool(view, "search_objects", {"query": "knife"}).results
        assert view._store is None, "search_objects reads only persisted stores: Kùzu stays closed"
        mat = view.vectors("entity").mat
        assert not mat.flags.owndata and isinstance(mat.base, np.memmap), "mapped, not read into memory"
    assert _results(bank, embedder, persist=True) == reference


def test_a_first_open_computes_and_writes_them(bank, embedder):
    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is None and view.persisted_written == store_dir(bank, P)
    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is not None and view.persisted_written is None


def test_a_write_to_the_database_makes_them_stale(bank, embedder):
    persist_bank(bank, [P])
    runner = CliRunner()
    before = runner.invoke(main, ["tool", str(bank), "search_objects", "knife", "--participant", P, "--json"])
    assert before.exit_code == 0, before.output
    first = json.loads(before.output)["results"][0]
    r = runner.invoke(main, ["query", str(bank), "MATCH (e:Entity) WHERE e.id = $id SET e.name = 'zzz renamed'",
                             "-p", "id", first["entity_id"], "--participant", P, "--write"])
    assert r.exit_code == 0, r.output
    sha = Bank(bank).manifest()["participants"][P]["integrity"]["sha256"]
    with pytest.raises(StaleStores, match="stale"):
        PersistedStores.open(bank, P, sha, Bank(bank).manifest().get("embed_model"))
    after = runner.invoke(main, ["tool", str(bank), "search_objects", "knife", "--participant", P, "--json"])
    assert after.exit_code == 0, after.output
    renamed = {o["entity_id"]: o["name"] for o in json.loads(after.output)["results"]}
    assert renamed.get(first["entity_id"]) == "zzz renamed", "the stale stores were not read"
    assert json.loads((store_dir(bank, P) / "meta.json").read_text())["db_sha256"] == sha, "written again"


@pytest.mark.parametrize("victim", ["vectors-entity.npy", "bm25-entity.json", "bm25-segment-tfs.npy",
                                    "graph-seg_entities.npy", "rows_tool_entities.json"])
def test_a_damaged_file_is_detected_and_not_used(bank, embedder, caplog, victim):
    reference = _results(bank, embedder, persist=False)
    persist_bank(bank, [P])
    path = store_dir(bank, P) / victim
    data = bytearray(path.read_bytes())
    data[-3] ^= 0x01  # one bit: still parses, wrong values
    path.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING, logger="memora_graph.integrity"):
        with MemoryView.open(bank, P, embedder) as view:
            assert view._persisted is None
    assert any(victim in r.getMessage() and "damaged" in r.getMessage() for r in caplog.records)
    assert _results(bank, embedder, persist=True) == reference
    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is not None, "written again, whole"


def test_a_file_damaged_after_opening_is_not_used(bank, embedder, caplog):
    reference = _results(bank, embedder, persist=False)
    persist_bank(bank, [P])
    with MemoryView.open(bank, P, embedder) as view:
        stores = view._persisted
        stores._checked.discard("vectors-segment.npy")  # as if not yet read in this process
        path = stores.root / "vectors-segment.npy"
        path.write_bytes(path.read_bytes()[:-4] + b"\0\0\0\0")
        with caplog.at_level(logging.WARNING, logger="memora_graph.integrity"):
            got = json.dumps(call_tool(view, "search", {"query": "wash the pan"}).as_json(), sort_keys=True)
    assert got == reference[0]
    assert any("damaged" in r.getMessage() for r in caplog.records)


def test_an_open_hashes_only_files_changed_since_one_was_hashed(bank, embedder, monkeypatch, caplog):
    """A process that hashed every file records their stat; a later open hashes only a file whose
    stat differs, so a bit flipped in place (its times put back) is still caught."""
    from memora_graph.retrieve import persist

    reference = _results(bank, embedder, persist=False)
    persist_bank(bank, [P])
    monkeypatch.setattr(persist, "RACY_S", 0.0)  # (otherwise: files changed 2 s before their hashing are hashed again)
    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is not None
    assert (store_dir(bank, P) / "verified.json").is_file()
    hashed = _count_hashes(monkeypatch)
    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is not None
    assert hashed == [], "unchanged files were hashed again"
    _flip_keeping_size_and_mtime(store_dir(bank, P) / "graph-pairs.npy", -3)  # the change time still moved
    with caplog.at_level(logging.WARNING, logger="memora_graph.integrity"):
        with MemoryView.open(bank, P, embedder) as view:
            assert view._persisted is None
    assert hashed[0] == "graph-pairs.npy", "only the changed file is hashed (then all, as they are written again)"
    assert any("graph-pairs.npy" in r.getMessage() and "damaged" in r.getMessage() for r in caplog.records)
    assert _results(bank, embedder, persist=True) == reference


def test_no_verify_never_reads_them(bank, embedder, monkeypatch):
    persist_bank(bank, [P])
    monkeypatch.setenv("MEMORA_NO_VERIFY", "1")
    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is None and view.persisted_written is None


def test_forget_removes_them(bank):
    persist_bank(bank, [P])
    assert str(store_dir(bank, P)) in Bank(bank).forget(P)
    assert not store_dir(bank, P).exists()


def test_verify_reports_damaged_stores(bank):
    from memora_graph.integrity.verify import verify_bank

    assert verify_bank(bank, [P]).rows[0]["tool_stores"].startswith("none")
    persist_bank(bank, [P])
    assert verify_bank(bank, [P]).ok and verify_bank(bank, [P]).rows[0]["tool_stores"] == "ok"
    path = store_dir(bank, P) / "ids-entity.json"
    path.write_text(path.read_text().replace(f'"{P}:', f'"{P}:x', 1))
    report = verify_bank(bank, [P])
    assert not report.ok and report.rows[0]["tool_stores"] == "damaged"
    assert any("ids-entity.json: damaged" in line for line in report.rows[0]["problems"])


def test_perf_startup_prints_its_figures(bank):
    r = CliRunner().invoke(main, ["perf", "startup", str(bank), "--participant", P, "--repeat", "1",
                                  "--query", "knife"])
    assert r.exit_code == 0, r.output
    for label in ("memora --help", "(no persisted stores: Kùzu)", "(first call: computes and writes them)",
                  "(persisted stores)"):
        assert label in r.output
    assert "heavy modules imported by `memora --help`: none" in r.output
    assert store_dir(bank, P).is_dir()


def test_the_writer_stamps_its_files_so_a_first_open_hashes_none_and_a_later_change_is_caught(
        bank, embedder, monkeypatch, caplog):
    """The process that writes the stores hashed every file as it wrote it: it records their stat
    (once they are RACY_S old), so the first open elsewhere reads stat only; a file changed after
    the stamp, its size and mtime put back, is still hashed and refused."""
    from memora_graph.retrieve import persist

    monkeypatch.setattr(persist, "STAMP_WAIT_BYTES", 0)  # these few KB are worth the wait here
    persist_bank(bank, [P])
    stamps = json.loads((store_dir(bank, P) / "verified.json").read_text())
    meta = json.loads((store_dir(bank, P) / "meta.json").read_text())
    assert set(stamps["files"]) == set(meta["files"]), "every file written is stamped"
    assert all(max(st[2], st[3]) < stamps["at_ns"] - persist.RACY_S * 1e9 for st in stamps["files"].values())
    hashed = _count_hashes(monkeypatch)
    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is not None
    assert hashed == [], "the first open hashed files the writer had stamped"
    _flip_keeping_size_and_mtime(store_dir(bank, P) / "bm25-segment-tfs.npy", -1)
    with caplog.at_level(logging.WARNING, logger="memora_graph.integrity"):
        with MemoryView.open(bank, P, embedder) as view:
            assert view._persisted is None
    assert hashed[0] == "bm25-segment-tfs.npy"
    assert any("bm25-segment-tfs.npy" in r.getMessage() and "damaged" in r.getMessage() for r in caplog.records)


def test_a_copied_bank_is_hashed_once_then_read_by_its_new_stamps(bank, embedder, monkeypatch, tmp_path):
    """A copy of a bank (`cp -r`, a restore) gives every store file a new inode, so no stamp
    vouches for it: the first open hashes them all, records their stat again, and the next open
    hashes none (before, the stale stamps were kept and every open hashed every file: 0.84 s at
    1,000 h)."""
    from memora_graph.retrieve import persist

    monkeypatch.setattr(persist, "STAMP_WAIT_BYTES", 0)
    persist_bank(bank, [P])
    copy = tmp_path / "copy"
    shutil.copytree(bank, copy)
    monkeypatch.setattr(persist, "RACY_S", 0.0)  # the copy's files are as young as the test
    hashed = _count_hashes(monkeypatch)
    with MemoryView.open(copy, P, embedder) as view:
        assert view._persisted is not None
    files = set(json.loads((store_dir(copy, P) / "meta.json").read_text())["files"])
    assert set(hashed) == files, "a copied file's old stamp was trusted"
    hashed.clear()
    with MemoryView.open(copy, P, embedder) as view:
        assert view._persisted is not None
    assert hashed == [], "the second open of the copy hashed its files again"


def test_a_writer_stamps_no_file_younger_than_racy_s(bank, monkeypatch):
    """Files written less than RACY_S ago, too small to wait for, are left to the first open to hash."""
    from memora_graph.retrieve import persist

    monkeypatch.setattr(persist, "STAMP_WAIT_BYTES", 1 << 40)
    # every file is young however long the write takes (on a loaded machine it can take over 2 s,
    # and the files written first would then rightly be stamped)
    monkeypatch.setattr(persist, "RACY_S", 3600.0)
    persist_bank(bank, [P])
    assert not (store_dir(bank, P) / "verified.json").exists()
    stores = PersistedStores.open(bank, P, Bank(bank).manifest()["participants"][P]["integrity"]["sha256"],
                                  json.loads((store_dir(bank, P) / "meta.json").read_text())["embed_model"])
    assert stores._checked == set(stores.meta["files"]), "every file hashed at the first open"


def test_stores_written_part_by_part_are_the_files_a_warm_view_writes(bank, embedder, tmp_path):
    """`persist_bank` drops each part from the view once written (and lays rows end to end one at
    a time) so that a long memory's write holds one part at a time; every file is byte for byte
    the one a view that keeps all it loaded writes (MemoryView.open's first open)."""
    other = tmp_path / "other"
    shutil.copytree(bank, other)
    assert persist_bank(bank, [P]).written == [store_dir(bank, P)]
    with MemoryView.open(other, P, embedder) as view:
        assert view.persisted_written == store_dir(other, P)
        assert "segment" in view.__dict__["_vector_cache"]  # kept for the calls that follow
    got = json.loads((store_dir(bank, P) / "meta.json").read_text())["files"]
    want = json.loads((store_dir(other, P) / "meta.json").read_text())["files"]
    assert len(got) > 40 and got == want


def test_every_persisted_row_query_orders_its_rows():
    """The persisted rows files are hashed and compared byte for byte: a participant-wide query
    whose rows are kept must give them in one order, never Kùzu's scan order (which varies with
    its threads; `_tool_inferred_links` once made two writes of one bank differ)."""
    from memora_graph.queries import get_query
    from memora_graph.retrieve.persist import ROW_QUERIES

    for name in ROW_QUERIES:
        assert "ORDER BY" in get_query(name).cypher.upper(), name


def _forge(root, name: str, edit) -> None:
    """Edit a store file, then rewrite its meta.json hash (and the stamps) to match, as an
    attacker who reads persist.py would: only the manifest's record still tells."""
    import hashlib
    import os

    path = root / name
    edit(path)
    meta = json.loads((root / "meta.json").read_text())
    meta["files"][name] = hashlib.sha256(path.read_bytes()).hexdigest()
    (root / "meta.json").write_text(json.dumps(meta, indent=1, sort_keys=True))
    stamps_path = root / "verified.json"
    if stamps_path.exists():
        stamps = json.loads(stamps_path.read_text())
        st = path.stat()
        stamps["files"][name] = [st.st_size, st.st_ino, st.st_mtime_ns, st.st_ctime_ns]
        stamps["at_ns"] = max(st.st_mtime_ns, st.st_ctime_ns) + 10**10
        stamps_path.write_text(json.dumps(stamps))
        os.utime(root / "meta.json")


def test_a_store_file_edited_with_its_meta_updated_fails_verify_by_name_and_is_never_served(bank, embedder):
    """The issue's attack: a persisted row and a .npy edited on disk, their hashes written into the
    store's own meta.json (and its stamps): `memora verify` fails naming the files, and `memora
    tool` serves the database's row, not the edited one; the stores are then written again."""
    from memora_graph.integrity.verify import verify_bank

    runner = CliRunner()
    persist_bank(bank, [P])
    before = runner.invoke(main, ["tool", str(bank), "search_objects", "knife", "--participant", P, "--json"])
    assert before.exit_code == 0, before.output
    first = json.loads(before.output)["results"][0]
    root = store_dir(bank, P)
    rows = json.loads((root / "rows_tool_entities.json").read_text())
    assert any(r.get("id") == first["entity_id"] for r in rows)
    forged = [{**r, "name": "forged name"} if r.get("id") == first["entity_id"] else r for r in rows]
    _forge(root, "rows_tool_entities.json", lambda p: p.write_text(json.dumps(forged, ensure_ascii=False)))

    def flip(p):
        data = bytearray(p.read_bytes())
        data[-3] ^= 0x01
        p.write_bytes(bytes(data))

    _forge(root, "vectors-entity.npy", flip)

    report = verify_bank(bank, [P])
    assert not report.ok and report.rows[0]["tool_stores"] == "damaged"
    text = " ".join(report.rows[0]["problems"])
    assert "rows_tool_entities.json" in text and "vectors-entity.npy" in text, text
    r = runner.invoke(main, ["verify", str(bank)])
    assert r.exit_code != 0 and "rows_tool_entities.json" in r.output, r.output

    after = runner.invoke(main, ["tool", str(bank), "search_objects", "knife", "--participant", P, "--json"])
    assert after.exit_code == 0, after.output
    assert "forged name" not in after.output
    assert "meta.json: damaged" in after.output, "the reader says why it read the database"
    assert json.loads(after.stdout)["results"][0]["name"] == first["name"]
    assert verify_bank(bank, [P]).ok, "the reader wrote them again, recorded"
    assert "forged name" not in (root / "rows_tool_entities.json").read_text()


def test_stores_are_recorded_in_the_manifest_and_unrecorded_ones_are_not_read(bank, embedder):
    """The manifest's record ties the stores to the database's recorded sha256; stores it holds
    no record of (an older bank's, or a record removed) are never read, and written again."""
    persist_bank(bank, [P])
    entry = Bank(bank).manifest()["participants"][P]
    record = entry["derived"]["tools"]
    meta = json.loads((store_dir(bank, P) / "meta.json").read_text())
    assert record["of"] == entry["integrity"]["sha256"] and record["files"] == meta["files"]
    Bank(bank).derived.drop(P, "tools")
    with pytest.raises(StaleStores, match="not recorded"):
        PersistedStores.open(bank, P, entry["integrity"]["sha256"], meta["embed_model"])
    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is None and view.persisted_written == store_dir(bank, P)
    with MemoryView.open(bank, P, embedder) as view:
        assert view._persisted is not None

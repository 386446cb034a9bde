import json
import os
import signal
import subprocess
import sys
import time

import polars as pl
import pytest

from memora_graph.bank import Bank
from memora_graph.errors import BankError, StoreError
from memora_graph.store import Store

MEMORA = [sys.executable, "-m", "memora_graph.cli"]


def test_small_bank_counts_and_history(small_bank):
    path, result = small_bank
    bank = Bank(path)
    assert bank.participants() == ["P09", "P37"]
    for r in result.participants:
        c = r.counts
        assert c["segments"] > 0 and c["entities"] > 0 and c["places"] > 0
        # every observation is kept as a state event, so the history is never smaller than the registry
        assert c["state_events"] >= c["entities"]
        assert sum(r.decisions.values()) >= c["state_events"]
    with bank.open("P37") as s:
        hist = s.run("object_history", participant="P37", object="knife")
        assert hist.height > 1
        assert hist["op"][0] == "ADD"
        keys = list(zip(hist["video"], hist["t"]))
        assert keys == sorted(keys)
        assert s.run("places_most_used", participant="P37")["turns"].sum() == s.run("store_counts", participant="P37")["segments"][0]


def test_participant_scoping(small_bank):
    path, _ = small_bank
    with Bank(path).open("P09") as s:
        assert s.run("entities", participant="P37").is_empty()
        assert not s.run("entities", participant="P09").is_empty()


def test_rebuild_adds_nothing(small_bank, tmp_path):
    path, result = small_bank
    from memora_graph.pipeline import build_bank

    again = build_bank(path, ["P09"])
    assert again.participants[0].videos_built == 0
    assert again.participants[0].counts == next(r for r in result.participants if r.participant == "P09").counts


def _staged(bank, participant="P07"):
    from memora_graph.form.staging import Staging

    return Staging(bank / ".staging" / participant).entries()


def test_resume_after_kill_matches_a_clean_build(tmp_path):
    killed = tmp_path / "killed"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([*MEMORA, "build", str(killed), "--participants", "P07", "--quiet"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while len(_staged(killed)) < 3 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, "build finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    kept = len(_staged(killed))
    assert kept >= 3
    from memora_graph.pipeline import build_bank

    resumed = build_bank(killed, ["P07"]).participants[0]
    assert resumed.videos_skipped == kept  # finished videos are not redone
    clean = build_bank(tmp_path / "clean", ["P07"]).participants[0]
    assert resumed.counts == clean.counts
    assert resumed.decisions == clean.decisions
    with Bank(killed).open("P07") as s:
        ids = s.query("MATCH (x:StateEvent) RETURN x.id AS id")["id"]
        assert ids.n_unique() == ids.len()
    assert not _staged(killed)


def test_lock_held_by_another_process(small_bank):
    path, _ = small_bank
    db = Bank(path).db_path("P09")
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from memora_graph.store import Store; s = Store(sys.argv[1], read_only=False); "
        "print('ready', flush=True); time.sleep(30)"), str(db)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "ready"
        with pytest.raises(StoreError, match="locked by another process"):
            Store(db)
    finally:
        holder.kill()
        holder.wait()


def test_manifest_mismatch_is_reported(small_bank, tmp_path):
    import json
    import shutil

    path, _ = small_bank
    copy = tmp_path / "copy"
    shutil.copytree(path, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["participants"]["P09"]["counts"]["segments"] += 1
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BankError, match="does not match manifest.json"):
        Bank(copy).open("P09")
    with pytest.raises(BankError, match="not in this bank"):
        Bank(copy).open("P01")


def test_a_bulk_load_in_chunks_gives_the_same_rows(tmp_path, monkeypatch):
    """The bulk load COPYs a table a chunk of videos at a time (its memory no longer grows with
    the hours); every row of the database is the one a single COPY per table gives."""
    from memora_graph.form import build as form_build
    from memora_graph.pipeline import build_bank

    build_bank(tmp_path / "whole", ["P37"])  # not the session's small bank: other tests write to it
    monkeypatch.setattr(form_build, "COPY_CHUNK_ROWS", 7)  # many chunks even for a small participant
    build_bank(tmp_path / "chunked", ["P37"])

    def dump(path):
        with Bank(path).open("P37", read_only=True) as store:
            nodes = sorted((r["tbl"], json.dumps({k: v for k, v in r["node"].items() if k != "_ID"}, sort_keys=True,
                                                 default=str))  # (Kùzu's internal offsets: a parallel COPY's order)
                           for r in store.rows("_export_nodes", participant="P37")
                           if r["tbl"] not in ("Video", "ModelCall"))  # build times and ids of the run
            rels = store.query("MATCH (a)-[r]->(b) WHERE a.participant = $p RETURN label(r) AS rel, a.id AS a, b.id AS b",
                               {"p": "P37"}).sort("rel", "a", "b").rows()
        return nodes, rels

    got, want = dump(tmp_path / "chunked"), dump(tmp_path / "whole")
    assert len(got[0]) > 100 and got == want


def _records(path, p):
    """Every node and edge of a participant's database with all its properties, but Kùzu's
    internal ids and the build's times (Video.built_at / build_seconds, ModelCall, migrations)."""
    skip = {"_ID", "_id", "_SRC", "_DST", "_src", "_dst", "_LABEL", "_label", "built_at", "build_seconds", "applied_at"}

    def clean(v):
        return json.dumps({k: x for k, x in v.items() if k not in skip}, sort_keys=True, default=str)

    with Bank(path).open(p, read_only=True) as store:
        nodes = sorted((r["tbl"], clean(r["node"])) for r in store.rows("_export_nodes", participant=p))
        rels = sorted((r["rel"], r["a"], r["b"], clean(r["r"])) for r in store.query(
            "MATCH (a)-[r]->(b) WHERE a.participant = $p RETURN label(r) AS rel, a.id AS a, b.id AS b, r",
            {"p": p}).to_dicts())
    return nodes, rels


def test_a_first_load_in_many_transactions_gives_the_same_records(tmp_path, monkeypatch):
    """A participant's first load commits and checkpoints a run of videos at a time (its memory
    no longer grows with the hours); with one video per transaction every node and edge, every
    property, is the one a load of all the videos at once gives, and the database file appears
    only when the load is whole."""
    from memora_graph.form import build as form_build
    from memora_graph.pipeline import build_bank

    build_bank(tmp_path / "whole", ["P37"])  # P37's few videos: one transaction
    chunks, commits = [], []
    real_load_chunks, real_checkpoint = form_build.load_chunks, Store.checkpoint
    monkeypatch.setattr(form_build, "LOAD_CHUNK_BYTES", 1)  # one video per transaction

    def counted_chunks(staged, budget=None):
        for c in real_load_chunks(staged, budget):
            chunks.append(len(c))
            yield c

    def checkpoint(store):
        assert store.path.name == "P37.kuzu.load" and not (store.path.parent / "P37.kuzu").exists()
        commits.append(store.path.name)
        real_checkpoint(store)

    monkeypatch.setattr(form_build, "load_chunks", counted_chunks)
    monkeypatch.setattr(Store, "checkpoint", checkpoint)
    build_bank(tmp_path / "chunked", ["P37"])
    videos = Bank(tmp_path / "chunked").manifest()["participants"]["P37"]["videos"]
    assert chunks == [1] * len(videos) and len(commits) == len(videos) + 1 and len(videos) > 1
    assert not list((tmp_path / "chunked").glob("P37.kuzu.load*"))
    got, want = _records(tmp_path / "chunked", "P37"), _records(tmp_path / "whole", "P37")
    assert len(got[0]) > 100 and len(got[1]) > 100
    assert got == want


def test_a_first_load_stopped_midway_leaves_no_database_and_resumes(tmp_path, monkeypatch):
    """Interrupted between two of its transactions, a first load leaves no database (only the
    staged videos and the write mark, as an interrupted single-transaction load did), the next
    build redoes it whole, and a side file a killed load left behind is removed, never used."""
    from memora_graph.form import build as form_build
    from memora_graph.pipeline import build_bank

    monkeypatch.setattr(form_build, "LOAD_CHUNK_BYTES", 1)
    real_checkpoint, calls = Store.checkpoint, []

    def interrupted(store):
        real_checkpoint(store)
        calls.append(1)
        if len(calls) == 3:  # the registry and two videos are in the side file
            raise KeyboardInterrupt

    monkeypatch.setattr(Store, "checkpoint", interrupted)
    path = tmp_path / "bank"
    with pytest.raises(KeyboardInterrupt):
        build_bank(path, ["P37"])
    bank = Bank(path)
    assert not bank.db_path("P37").exists() and not list(path.glob("P37.kuzu*"))
    assert bank.manifest()["writing"]["P37"]["op"] == "build"
    assert _staged(path, "P37")  # kept, to resume
    assert any(p == "P37" and "build was interrupted" in line for p, line in bank.notices())
    monkeypatch.setattr(Store, "checkpoint", real_checkpoint)
    side = path / "P37.kuzu.load"
    side.write_bytes(b"what a killed load left" * 100)  # as kill -9 would leave it
    (path / "P37.kuzu.load.wal").write_bytes(b"x" * 100)
    resumed = build_bank(path, ["P37"]).participants[0]
    assert resumed.videos_skipped == len(Bank(path).manifest()["participants"]["P37"]["videos"])
    assert not list(path.glob("P37.kuzu.load*")) and not _staged(path, "P37")
    assert "writing" not in Bank(path).manifest()
    build_bank(tmp_path / "clean", ["P37"])
    assert _records(path, "P37") == _records(tmp_path / "clean", "P37")


def test_a_failed_first_load_removes_its_side_file(tmp_path, monkeypatch):
    from memora_graph.pipeline import build_bank

    def broken(store):
        raise StoreError(f"{store.path}: simulated failure")

    monkeypatch.setattr(Store, "checkpoint", broken)
    with pytest.raises(StoreError, match="simulated"):
        build_bank(tmp_path / "bank", ["P37"])
    assert not (tmp_path / "bank").exists()  # the bank this build created is removed whole, as before

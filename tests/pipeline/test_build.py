import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

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
        # an object's history, a video at a time: the pages are the whole history, each in time order
        pages = [s.run("object_history", participant="P37", object="knife", video=v)
                 for v in s.run("videos", participant="P37")["video"]]
        assert all(p["video"].unique().to_list() == [v] for p, v in zip(pages, s.run("videos", participant="P37")["video"])
                   if p.height)
        assert all(p["t"].to_list() == sorted(p["t"]) for p in pages)
        hist = pl.concat([p for p in pages if p.height])
        whole = s.query("MATCH (e:Entity)-[:HAS_STATE]->(x:StateEvent) WHERE e.participant = $p AND e.object_id = 'knife' "
                        "RETURN count(x) AS n", {"p": "P37"})["n"][0]
        assert hist.height == whole > 1
        assert hist["op"][0] == "ADD"
        # the editor's decisions about it, a video at a time too
        ops = [s.run("edit_log", participant="P37", object="knife", video=v) for v in s.run("videos", participant="P37")["video"]]
        assert all(p["t"].to_list() == sorted(p["t"]) for p in ops)
        every = s.query("MATCH (o:EditOp)-[:EDITED]->(e:Entity) WHERE e.participant = $p AND e.object_id = 'knife' "
                        "RETURN count(o) AS n", {"p": "P37"})["n"][0]
        assert sum(p.height for p in ops) == every > 1
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


def _staged(bank):
    from memora_graph.form.staging import Staging

    return Staging(bank / ".staging" / "P07").entries()


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


def test_a_bulk_load_through_parquet_files_gives_the_rows_of_in_memory_copies(tmp_path, monkeypatch):
    """The bulk load COPYs each table from a Parquet file written a video at a time (Kùzu reads a
    file in batches; in-memory frames were held whole until the commit); every row of the
    database is the one a COPY of the whole table's frame gives, and no load file is left."""
    from memora_graph.form import build as form_build
    from memora_graph.pipeline import build_bank

    monkeypatch.chdir(tmp_path)
    build_bank("files", ["P37"])  # a relative bank path, as `memora build banks/epic` gives
    assert not list((tmp_path / "files").rglob("*.parquet")), "the load's files are removed"
    assert not (tmp_path / "files" / ".staging" / "P37").exists()

    def copy_frames(self, table, frames):
        frames = list(frames)
        if frames:
            self.store.copy(table, pl.concat(frames, how="vertical_relaxed"))

    monkeypatch.setattr(form_build.ParticipantBuilder, "_copy_chunks", copy_frames)
    build_bank(tmp_path / "frames", ["P37"])

    def dump(path):
        with Bank(path).open("P37", read_only=True) as store:
            nodes = sorted((r["tbl"], json.dumps({k: v for k, v in r["node"].items() if k != "_ID"}, sort_keys=True,
                                                 default=str))  # (Kùzu's internal offsets: a parallel COPY's order)
                           for r in store.rows("_export_nodes", participant="P37")
                           if r["tbl"] not in ("Video", "ModelCall"))  # build times and ids of the run
            rels = store.query("MATCH (a)-[r]->(b) WHERE a.participant = $p RETURN label(r) AS rel, a.id AS a, b.id AS b",
                               {"p": "P37"}).sort("rel", "a", "b").rows()
        return nodes, rels

    got, want = dump(tmp_path / "files"), dump(tmp_path / "frames")
    assert len(got[0]) > 100 and got == want
    assert any(t == "Segment" and '"emb": [' in n for t, n in got[0]), "the vectors are compared too"


def test_a_load_file_left_by_a_killed_build_is_removed_by_the_next(tmp_path):
    """A build killed during its bulk load leaves the table file it was writing in the staging
    folder; the next build removes it and builds the participant whole."""
    from memora_graph.form import build as form_build
    from memora_graph.pipeline import build_bank

    path = tmp_path / "bank"
    left = path / ".staging" / "P37" / form_build.LOAD_DIR
    left.mkdir(parents=True)
    (left / "Segment.parquet").write_bytes(b"PAR1 half written")
    build_bank(path, ["P37"])
    assert not left.exists() and not (path / ".staging" / "P37").exists()
    assert Bank(path).manifest()["participants"]["P37"]["counts"]["segments"] > 0


def test_a_copy_statement_names_only_a_plain_absolute_file():
    from memora_graph import schema
    from memora_graph.errors import StoreError

    table = schema.table("Segment")
    assert table.copy_file_statement(Path("/tmp/x/Segment.parquet")) == "COPY Segment FROM '/tmp/x/Segment.parquet'"
    for bad in ("relative/Segment.parquet", "/tmp/it's.parquet", '/tmp/a"b.parquet', "/tmp/a\\b.parquet",
                "/tmp/a\nb.parquet"):
        with pytest.raises(StoreError, match="not a path a COPY statement can name"):
            table.copy_file_statement(Path(bad))


def test_verify_names_half_written_folders_of_a_killed_build_without_calling_the_bank_damaged(tmp_path):
    """What a build killed mid-video or mid-load leaves in the staging folder (`.NAME.tmp`,
    `.load.tmp`) is shown by `verify` as half-written, not as damage (the next build removes it:
    the test above); a file that no build writes there is still reported as foreign."""
    from memora_graph.form import build as form_build
    from memora_graph.integrity.verify import verify_bank
    from memora_graph.pipeline import build_bank

    path = tmp_path / "bank"
    build_bank(path, ["P37"])
    staging = path / ".staging" / "P37"
    (staging / form_build.LOAD_DIR).mkdir(parents=True)
    (staging / form_build.LOAD_DIR / "Segment.parquet").write_bytes(b"PAR1 half written")
    (staging / ".0003_P37_101.tmp").mkdir()
    report = verify_bank(path)
    row = next(r for r in report.rows if r["participant"] == "P37")
    assert report.ok, row["problems"]
    assert "2 half-written folder(s)" in row["staging"]
    (staging / "notes.txt").write_text("mine")
    report = verify_bank(path)
    row = next(r for r in report.rows if r["participant"] == "P37")
    assert not report.ok and row["problems"] == [f"{staging / 'notes.txt'}: not a staged video (never opened by a build; remove it)"]
    (staging / "notes.txt").unlink()
    assert verify_bank(path).ok

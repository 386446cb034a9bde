"""The intake journal (form/intake.py): every acknowledged moment's input is durable before
`remember` answers, the journal empties at each checkpoint, and a log Kùzu cannot replay (or
replays short) loses no acknowledged moment: the database opens as its last checkpoint left it
and the journal re-applies the rest by key. Real Kùzu in tmp dirs, the bundled MiniLM."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from memora_graph.bank import Bank
from memora_graph.errors import StoreError
from memora_graph.files import RECOVERY
from memora_graph.form.checkpoint import CheckpointPolicy
from memora_graph.form.intake import entries, journal_path
from memora_graph.form.live import LiveWriter
from memora_graph.integrity.verify import accept, verify_bank
from support.live import moments


def _journal(bank: Path) -> list[dict]:
    path = journal_path(bank, "P01")
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def _keys(memory: LiveWriter) -> dict[str, str]:
    rows = memory.store.query("MATCH (r:Remembered) WHERE r.participant = $p RETURN r.id AS id, r.segment AS s",
                              {"p": "P01"}).to_dicts()
    return {r["id"]: r["s"] for r in rows}


def test_each_moment_is_journaled_before_remember_answers_and_a_checkpoint_empties_it(tmp_path, monkeypatch):
    bank = tmp_path / "bank"
    synced = []
    real_fsync = os.fdatasync
    with LiveWriter(bank, "P01", checkpoint=CheckpointPolicy(0, 0, 0)) as memory:
        journal_fd = memory.intake._fd
        monkeypatch.setattr(os, "fdatasync", lambda fd: (synced.append(fd), real_fsync(fd))[1])
        done = []
        for m in moments(5):
            done.append(memory.remember(m))
            assert _journal(bank)[-1]["key"] == done[-1].key  # in the file when remember returned
        lines = _journal(bank)
        assert [e["key"] for e in lines] == [d.key for d in done]
        assert lines[0]["moment"] == {"video": "home-1", "start": 0.0, "end": 3.0, "text": "open the fridge"}
        assert synced.count(journal_fd) == 5  # one fsync of the journal per acknowledged moment
        assert memory.remember(moments(1)[0]).duplicate and len(_journal(bank)) == 5  # a retry journals nothing
        assert memory.checkpoint()
        assert journal_path(bank, "P01").stat().st_size == 0  # in the database file now
        memory.remember(moments(6)[5])
        assert [e["key"] for e in _journal(bank)] == [moments(6)[5].client_key()]
    assert journal_path(bank, "P01").stat().st_size == 0  # a clean close checkpoints: empty


def test_no_answer_before_the_journal_line_is_durable(tmp_path, monkeypatch):
    """A journal line that cannot be made durable fails the remember before its transaction
    (nothing written, no acknowledgement); a moment whose transaction fails is cancelled in the
    journal (never re-applied)."""
    bank = tmp_path / "bank"
    with LiveWriter(bank, "P01", checkpoint=CheckpointPolicy(0, 0, 0)) as memory:
        first = memory.remember(moments(1)[0])

        def refuse(fd):
            raise OSError(5, "Input/output error")

        with monkeypatch.context() as m:
            m.setattr(os, "fdatasync", refuse)
            with pytest.raises(OSError):
                memory.remember(moments(2)[1])

        def fail(*args):
            raise StoreError("the transaction failed")

        with monkeypatch.context() as m:
            m.setattr(memory, "_transaction", fail)
            with pytest.raises(StoreError):
                memory.remember(moments(3)[2])
        assert _journal(bank)[-1] == {"key": moments(3)[2].client_key(), "cancel": True}
        assert [e["key"] for e in entries(bank, "P01")] == [first.key]
        after = memory.remember(moments(4)[3])  # the writer goes on: the next turn, the next segment
        assert after.turn == 1 and not after.duplicate


def _killed_copy(tmp_path: Path, checkpointed: int, after: int) -> tuple[Path, dict[str, str]]:
    """A bank whose writer checkpointed after `checkpointed` moments and acknowledged `after` more,
    copied while open (the files a kill -9 leaves) and its write mark's process gone."""
    live, crashed = tmp_path / "live", tmp_path / "crashed"
    todo = moments(checkpointed + after)
    with LiveWriter(live, "P01", checkpoint=CheckpointPolicy(0, 0, 0)) as memory:
        acked = {}
        for m in todo[:checkpointed]:
            acked[m.client_key()] = memory.remember(m).segment
        assert memory.checkpoint()
        for m in todo[checkpointed:]:
            acked[m.client_key()] = memory.remember(m).segment
        shutil.copytree(live, crashed)
    gone = subprocess.Popen(["true"])
    gone.wait()
    manifest = json.loads((crashed / "manifest.json").read_text())
    manifest["writing"]["P01"]["pid"] = gone.pid
    (crashed / "manifest.json").write_text(json.dumps(manifest))
    assert len(_journal(crashed)) == after
    return crashed, acked


def _damage_log(bank: Path) -> bytes:
    """Overwrite 4 KB in the middle of the log with bytes Kùzu cannot read (it aborts replaying it,
    read-only and read-write alike: what a log that hits "duplicated primary key" amounts to)."""
    wal = bank / "P01.kuzu.wal"
    data = wal.read_bytes()
    cut = len(data) // 3
    damaged = data[:cut] + bytes(range(256)) * 16 + data[cut + 4096:]
    wal.write_bytes(damaged)
    return damaged


def test_a_log_kuzu_cannot_replay_loses_no_acknowledged_moment(tmp_path):
    bank, acked = _killed_copy(tmp_path, checkpointed=10, after=20)
    damaged = _damage_log(bank)
    row = verify_bank(bank).rows[0]
    assert "journal" in row["kinds"] and "cannot_open" not in row["kinds"], row["problems"]
    assert row["log"] == "cannot be replayed"
    assert "re-applies the 20 moment(s) it holds" in " ".join(row["problems"])
    with LiveWriter(bank, "P01") as memory:  # sets the log aside, opens the checkpoint, re-applies the journal
        stored = _keys(memory)
    assert {k: stored.get(k) for k in acked} == acked, "an acknowledged moment was lost or got another segment"
    kept = list((bank / RECOVERY).glob("unreplayable-P01.kuzu-*/P01.kuzu.wal"))
    assert len(kept) == 1 and kept[0].read_bytes() == damaged  # the log as found, never deleted
    assert (kept[0].parent / "P01.kuzu").is_file()  # and the file the checkpoint left, written again from its rows
    assert journal_path(bank, "P01").stat().st_size == 0
    assert verify_bank(bank).ok


def test_verify_accept_recovers_from_the_journal(tmp_path):
    bank, acked = _killed_copy(tmp_path, checkpointed=5, after=8)
    _damage_log(bank)
    accept(bank, "P01")
    assert verify_bank(bank).ok
    with LiveWriter(bank, "P01") as memory:
        assert {k: v for k, v in _keys(memory).items() if k in acked} == acked
    removed = Bank(bank).forget("P01")  # forgetting a person takes their journal and the logs set aside too
    assert str(journal_path(bank, "P01")) in removed and not journal_path(bank, "P01").exists()
    assert not list((bank / RECOVERY).glob("*P01.kuzu-*"))


def test_a_log_replayed_short_is_completed_from_the_journal(tmp_path):
    """Kùzu replays a log whose head is damaged as if it were empty, without an error: the
    writer that opens it re-applies what the journal holds and the database lacks."""
    bank, acked = _killed_copy(tmp_path, checkpointed=6, after=10)
    wal = bank / "P01.kuzu.wal"
    wal.write_bytes(b"\xff" * 64 + wal.read_bytes()[64:])
    told = []  # a server's hook: re-applied moments are not news to readers that open after the writer
    with LiveWriter(bank, "P01", on_commit=told.append) as memory:
        stored = _keys(memory)
    assert not told
    assert {k: stored.get(k) for k in acked} == acked
    assert verify_bank(bank).ok


def test_a_database_written_again_from_its_rows_keeps_every_row_and_index(small_bank, tmp_path):
    """A writer killed inside a checkpoint can leave a file whose primary-key index no longer
    matches its rows: Kùzu 0.11.3 then refuses new keys as duplicates at COMMIT, and the journal's
    moments were left out (the kill soak lost 2 of 387 so). Setting such a log aside writes the
    database again from its rows (`store.rebuild_from_rows`): every table keeps its rows, the
    optional indexes are made again, and the file as it was is kept."""
    from memora_graph.store import Store, rebuild_from_rows

    src, _ = small_bank
    bank = tmp_path / "bank"
    shutil.copytree(src, bank)
    db = bank / "P37.kuzu"
    with Store(db, read_only=False) as store:
        store.ensure_indexes(fts=True)
        before, indexes = store.table_counts("P37"), store.indexes()
    aside = tmp_path / "aside"
    aside.mkdir()
    old = rebuild_from_rows(db, aside)
    assert old == aside / "P37.kuzu" and old.is_file() and not (aside / "rows").exists()
    with Store(db, read_only=False) as store:
        assert store.table_counts("P37") == before and before["StateEvent"]["rows"] > 0
        assert store.indexes() == indexes and indexes
        n = store.query("MATCH (s:StateEvent) RETURN count(*) AS n").to_dicts()[0]["n"]
        store.query("CREATE (s:StateEvent {id: $id, participant: 'P37', ord: 0})", {"id": "P37:new@1"})
        assert store.query("MATCH (s:StateEvent) RETURN count(*) AS n").to_dicts()[0]["n"] == n + 1

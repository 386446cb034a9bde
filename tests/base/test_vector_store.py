"""The reader's text vectors: each text encoded alone (its vector never depends on the batch),
kept in an SQLite file per encoder and shared between processes and runs; a damaged or
unwritable cache costs speed, never a different vector."""

from __future__ import annotations

import logging
import os
import sqlite3
import subprocess
import sys

import numpy as np
import pytest

from memora_graph.embed import get_embedder
from memora_graph.vector_store import TextVectors, encoder_identity

TEXTS = ["take plate", "wash the plate in the sink", "put knife in drawer", "open fridge", "pour a squeeze of soap"]


@pytest.fixture(scope="module")
def query_encoder():
    return get_embedder().inner.query  # the default ONNX int8 query encoder, as the reader uses it


def _alone(encoder, texts):
    return np.stack([encoder.encode([t], kind="query")[0] for t in texts])


def test_each_text_alone_whatever_the_batch(query_encoder, tmp_path):
    tv = TextVectors(query_encoder, root=tmp_path)
    first = tv.encode(TEXTS[:1])
    tv2 = TextVectors(query_encoder, persist=False)
    together = tv2.encode(list(reversed(TEXTS)))
    assert np.array_equal(first[0], together[-1])  # bit for bit: the companions do not matter
    assert np.array_equal(together, _alone(query_encoder, list(reversed(TEXTS))))
    assert tv2.encoded == len(TEXTS) and tv2.path is None
    again = tv2.encode(TEXTS + TEXTS)  # repeats are looked up, not encoded again
    assert tv2.encoded == len(TEXTS) and np.array_equal(again[:5], again[5:])


def test_vectors_are_kept_between_processes(query_encoder, tmp_path):
    tv = TextVectors(query_encoder, root=tmp_path)
    want = tv.encode(TEXTS)
    assert tv.encoded == len(TEXTS) and tv.path.parent == tmp_path / "vectors"
    assert encoder_identity(query_encoder) in tv.path.name and "int8" in tv.path.name
    tv.close()
    later = TextVectors(query_encoder, root=tmp_path)  # a later run
    got = later.encode(TEXTS[::-1])
    assert later.encoded == 0 and later.from_disk == len(TEXTS)
    assert np.array_equal(got, want[::-1])
    # another process (the evaluation's second worker) reads them and adds its own
    code = ("import sys, numpy as np; from memora_graph.embed import get_embedder; "
            "from memora_graph.vector_store import TextVectors; "
            "tv = TextVectors(get_embedder().inner.query, root=sys.argv[1]); "
            "v = tv.encode(['take plate', 'close the tap']); "
            "print(tv.from_disk, tv.encoded, np.asarray(v[0], dtype=np.float32).tobytes().hex())")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, check=True)
    from_disk, encoded, hex0 = out.stdout.split()
    assert (from_disk, encoded) == ("1", "1") and bytes.fromhex(hex0) == want[0].tobytes()
    later.close()
    fresh = TextVectors(query_encoder, root=tmp_path)
    fresh.encode(["close the tap"])
    assert fresh.from_disk == 1 and fresh.encoded == 0


def test_a_damaged_file_is_set_aside_and_the_vectors_stay_right(query_encoder, tmp_path, caplog):
    tv = TextVectors(query_encoder, root=tmp_path)
    want = tv.encode(TEXTS)
    path = tv.path
    tv.close()
    for suffix in ("-wal", "-shm"):
        if os.path.exists(f"{path}{suffix}"):
            os.remove(f"{path}{suffix}")
    path.write_bytes(b"this is not an SQLite database" * 100)
    with caplog.at_level(logging.WARNING, logger="memora_graph"):
        tv = TextVectors(query_encoder, root=tmp_path)
        got = tv.encode(TEXTS)
    assert np.array_equal(got, want) and tv.encoded == len(TEXTS)
    assert "is damaged" in caplog.text and path.name in caplog.text
    assert any(p.name.startswith(path.name + ".damaged-") for p in path.parent.iterdir())
    tv.close()
    assert TextVectors(query_encoder, root=tmp_path).encode(TEXTS[:2]).shape == (2, want.shape[1])


def test_memory_only_when_switched_off_or_unwritable(query_encoder, tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("MEMORA_VECTOR_CACHE", "0")
    tv = TextVectors(query_encoder, root=tmp_path)
    want = tv.encode(TEXTS)
    assert tv.path is None and not (tmp_path / "vectors").exists()
    monkeypatch.delenv("MEMORA_VECTOR_CACHE")
    blocked = tmp_path / "blocked"
    blocked.write_text("a file where the cache directory would go")
    with caplog.at_level(logging.WARNING, logger="memora_graph"):
        tv = TextVectors(query_encoder, root=blocked)
        got = tv.encode(TEXTS)
    assert tv.path is None and "kept in memory only" in caplog.text
    assert np.array_equal(got, want)


def test_a_busy_file_is_not_taken_for_damaged(query_encoder, tmp_path, monkeypatch, caplog):
    """A read that SQLite refuses as locked (another process held it past the timeout) costs an
    encode, not the file."""
    from memora_graph import vector_store

    tv = TextVectors(query_encoder, root=tmp_path)
    want = tv.encode(TEXTS)
    tv.close()

    def busy(self, keys):
        raise sqlite3.OperationalError("database is locked")

    monkeypatch.setattr(vector_store._Disk, "get", busy)
    with caplog.at_level(logging.WARNING, logger="memora_graph"):
        later = TextVectors(query_encoder, root=tmp_path)
        got = later.encode(TEXTS)
    assert np.array_equal(got, want) and later.encoded == len(TEXTS) and later.path is not None
    assert "could not read" in caplog.text and "damaged" not in caplog.text
    assert not any(".damaged-" in p.name for p in (tmp_path / "vectors").iterdir())


def test_a_file_locked_while_it_is_opened_is_left_alone(query_encoder, tmp_path, monkeypatch, caplog):
    """Two evaluation workers creating the file at once: one finds it locked while it switches the
    file to WAL. That lock is another process at work, not damage: the file is never set aside (the
    other worker is using it), and the vectors are computed in memory."""
    from memora_graph import vector_store

    tv = TextVectors(query_encoder, root=tmp_path)
    want = tv.encode(TEXTS)
    path = tv.path
    tv.close()
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")  # another process holds the file
    monkeypatch.setattr(vector_store, "BUSY_TIMEOUT_S", 0.05)
    try:
        with caplog.at_level(logging.WARNING, logger="memora_graph"):
            later = TextVectors(query_encoder, root=tmp_path)
            got = later.encode(TEXTS)
    finally:
        other.execute("ROLLBACK")
        other.close()
    assert np.array_equal(got, want) and later.path is None and later.encoded == len(TEXTS)
    assert "locked by another process" in caplog.text and "damaged" not in caplog.text
    assert not any(".damaged-" in p.name for p in (tmp_path / "vectors").iterdir())
    assert TextVectors(query_encoder, root=tmp_path).encode(TEXTS[:1]).shape[0] == 1  # the file still opens

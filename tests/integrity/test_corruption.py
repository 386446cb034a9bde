"""The corruption corpus: a damaged, edited, swapped or foreign file is a clear error naming the
file (exit 1), never a crash (a negative return code is a signal, e.g. SIGSEGV) and never an
answer served from damaged content (exit 0). `memora verify` reports each case the same way."""

from __future__ import annotations

import json

import pytest
from support.corrupt import CORPUS, memora

from memora_graph.integrity.verify import KINDS

QUERY = "MATCH (s:Segment) WHERE s.narrative CONTAINS 'stove' RETURN count(*) AS n"


@pytest.mark.parametrize("case", sorted(CORPUS))
def test_damage_is_a_clear_error_never_a_crash_or_an_answer(bank, case):
    named = CORPUS[case](bank)
    r = memora("query", bank, QUERY, "--participant", "P09", "--json")
    out = r.stdout + r.stderr
    assert r.returncode >= 0, f"{case}: crashed with signal {-r.returncode}"
    assert r.returncode == 1, f"{case}: served an answer: {out}"
    assert any(line.startswith("Error: ") for line in out.splitlines()) and named in out and "Traceback" not in out, out
    v = memora("verify", bank, "--json")
    assert v.returncode >= 0, f"{case}: verify crashed with signal {-v.returncode}"
    assert v.returncode == 1, f"{case}: verify found nothing wrong: {v.stdout}{v.stderr}"
    assert named in v.stdout + v.stderr
    rows = json.loads(v.stdout) if v.stdout.lstrip().startswith("[") else []  # (no rows: an unreadable manifest)
    for row in rows:  # each problem has its kind, a stable code scripts can test
        assert len(row["kinds"]) == len(row["problems"]) and set(row["kinds"]) <= set(KINDS), row
        assert bool(row["kinds"]) == (row["status"] == "problem"), row


def test_a_clean_bank_verifies_and_answers(bank):
    r = memora("query", bank, QUERY, "--participant", "P09", "--json")
    assert r.returncode == 0, r.stdout + r.stderr
    assert json.loads(r.stdout)[0]["n"] > 0
    v = memora("verify", bank, "--json")
    assert v.returncode == 0, v.stdout + v.stderr
    rows = json.loads(v.stdout)
    assert [(x["participant"], x["hash"], x["tables"], x["status"], x["kinds"], x["log"]) for x in rows] == [
        ("P09", "ok", "ok", "ok", [], "none"), ("P37", "ok", "ok", "ok", [], "none")]


def test_no_verify_bypasses_the_check_knowingly(bank):
    CORPUS["manifest_hash"](bank)  # the file is fine; its record is not
    assert memora("query", bank, QUERY, "--participant", "P09").returncode == 1
    r = memora("query", bank, QUERY, "--participant", "P09", "--json", "--no-verify")
    assert r.returncode == 0, r.stdout + r.stderr
    assert json.loads(r.stdout)[0]["n"] > 0


def test_a_hidden_participant_is_reported_by_readers(bank):
    CORPUS["manifest_entry_removed"](bank)
    r = memora("stats", bank, "--json")
    assert r.returncode == 0
    assert [s["participant"] for s in json.loads(r.stdout)] == ["P37"]
    assert "P09.kuzu: exists, but manifest.json does not list P09" in r.stderr


def test_readers_say_a_build_was_interrupted(bank):
    CORPUS["interrupted_write"](bank)
    r = memora("stats", bank, "--participant", "P37", "--json")
    assert r.returncode == 0
    assert "its build was interrupted" in r.stderr and "memora build" in r.stderr and "P09" in r.stderr


def test_swapped_files_name_the_owner(bank):
    CORPUS["swapped_files"](bank)
    r = memora("query", bank, QUERY, "--participant", "P09")
    assert r.returncode == 1 and "holds the database recorded for P37" in r.stdout + r.stderr


def test_an_edit_after_a_checked_open_is_still_caught(bank):
    """Readers skip re-hashing a file whose inode, size, mtime and ctime are those it last
    hashed to its record with; an edit changes ctime even when mtime is put back."""
    import os

    assert memora("query", bank, QUERY, "--participant", "P09").returncode == 0
    seen = json.loads((bank / ".verified.json").read_text())
    assert seen["P09"]["sha256"] == json.loads((bank / "manifest.json").read_text())["participants"]["P09"]["integrity"]["sha256"]
    db = bank / "P09.kuzu"
    st = db.stat()
    CORPUS["narration_edit"](bank)
    os.utime(db, ns=(st.st_atime_ns, st.st_mtime_ns))  # mtime as it was
    r = memora("query", bank, QUERY, "--participant", "P09")
    assert r.returncode == 1 and "does not match the sha256" in r.stdout + r.stderr

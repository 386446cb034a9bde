"""`memora query` end to end on a small real bank (P09, P37): none of the attacks writes a file,
reads /etc/passwd, reaches another participant's database or changes the bank; reads still
work; --write writes data into one participant only; time and memory limits hold."""

from __future__ import annotations

import hashlib
import json
import shutil

import pytest
from click.testing import CliRunner

from memora_graph.adhoc import _in_child, run_query
from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.cypher_guard import check_read_query
from memora_graph.errors import QueryTimeout, StoreError
from e2e.trust.corpus import ALLOWED, NEVER, attacks


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def clean_error(r) -> bool:
    """Exit code 1 with an `Error: ...` line, and no traceback."""
    return r.exit_code == 1 and r.output.startswith("Error: ") and (r.exception is None or isinstance(r.exception,
                                                                                                     SystemExit))


# files a read may refresh: the integrity check's record of files it found unchanged
READ_CACHES = (".verified.json",)


def digest(folder) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name not in READ_CACHES}


@pytest.fixture()
def bank(small_bank, tmp_path):
    path = tmp_path / "bank"
    shutil.copytree(small_bank[0], path)
    out = tmp_path / "out"
    out.mkdir()
    return path, out


def fill(statement: str, path, out) -> str:
    return statement.replace("{bank}", str(path)).replace("{other}", str(path / "P37.kuzu")).replace("{out}", str(out))


def test_no_attack_reaches_kuzu_and_the_bank_is_unchanged(bank):
    path, out = bank
    before = digest(path)
    failures = []
    for i, (kind, disguise, statement) in enumerate(attacks()):
        text = fill(statement, path, out)
        scope = ("--participant", "P09") if i % 3 else ()  # also the every-participant path
        for args in ([], ["--write"]) if kind != "data" else ([],):
            if "--write" in args and not scope:
                scope = ("--participant", "P09")
            r = invoke("query", path, text, *scope, *args)
            if not clean_error(r) or not r.output.startswith("Error: refused") or "root:" in r.output:
                failures.append((kind, disguise, args, r.exit_code, r.output[:200]))
    assert failures == []
    assert digest(path) == before
    assert list(out.iterdir()) == []


def test_reads_with_forbidden_words_in_strings_and_comments_run_and_change_nothing(bank):
    path, out = bank
    before = digest(path)
    with Bank(path).open("P09") as store:  # what the child process does, in this process for speed
        for statement in ALLOWED:
            s = check_read_query(fill(statement, path, out))
            store.query(s.text, {"participant": "P09"} if "participant" in s.params else {})
    r = invoke("query", path, "MATCH (e:Entity) WHERE e.name = 'copy' OR e.name = \"LOAD FROM '/etc/passwd'\" "
                              "RETURN e.participant AS p, count(*) AS n // CHECKPOINT", "--json")
    assert r.exit_code == 0, r.output
    r = invoke("query", path, fill(ALLOWED[6], path, out), "--participant", "P37", "--json")
    assert r.exit_code == 0 and json.loads(r.output) == [{"n": 1}], r.output
    assert digest(path) == before and list(out.iterdir()) == []


def test_participant_is_bound_and_conflicts_are_errors(bank):
    path, _ = bank
    q = "MATCH (e:Entity) WHERE e.participant = $participant RETURN e.participant AS p, count(*) AS n"
    r = invoke("query", path, q, "--json")  # $participant: each database's own participant
    assert r.exit_code == 0 and {x["p"] for x in json.loads(r.output)} == {"P09", "P37"}, r.output
    r = invoke("query", path, q, "-p", "participant", "P37", "--json")
    assert r.exit_code == 0 and [x["p"] for x in json.loads(r.output)] == ["P37"]
    for args, says in [(("-p", "participant", "P37", "--participant", "P09"), "disagree"),
                       (("--participant", ""), "not an empty string"),
                       (("-p", "participant", '["P09"]'), "one participant id"),
                       (("-p", "participant", "P11"), "not in this bank"),
                       (("-p", "y", "1", "--participant", "P09"), "has no $y")]:
        r = invoke("query", path, q, *args)
        assert clean_error(r) and says in r.output, (args, r.output)


def test_write_needs_one_participant_and_writes_only_there(bank):
    path, _ = bank
    before = digest(path)
    create = "CREATE (:Participant {id: 'X99', participant: 'X99'})"
    r = invoke("query", path, create, "--write")
    assert clean_error(r) and "--write writes into one participant's database" in r.output
    assert digest(path) == before
    r = invoke("query", path, create, "--write", "--participant", "P09")
    assert r.exit_code == 0, r.output
    after = digest(path)
    assert after["P37.kuzu"] == before["P37.kuzu"] and after["P09.kuzu"] != before["P09.kuzu"]
    entries = json.loads((path / "manifest.json").read_text())["participants"]
    assert entries["P09"]["integrity"]["sha256"] == after["P09.kuzu"]  # the write's new hash is recorded
    assert entries["P37"]["integrity"]["sha256"] == before["P37.kuzu"]
    r = invoke("query", path, "MATCH (p:Participant) RETURN p.id AS id ORDER BY id", "--participant", "P09", "--json")
    assert [x["id"] for x in json.loads(r.output)] == ["P09", "X99"]
    for _, statement in NEVER[:12]:
        r = invoke("query", path, fill(statement, path, path), "--write", "--participant", "P09")
        assert clean_error(r) and "refused" in r.output
    assert digest(path)["P09.kuzu"] == after["P09.kuzu"]


def test_timeout_stops_a_long_query(bank):
    path, _ = bank
    heavy = "UNWIND range(1, 20000) AS x UNWIND range(1, 20000) AS y WITH x, y WHERE (x * y) % 7 = 3 RETURN count(*) AS n"
    r = invoke("query", path, heavy, "--participant", "P09", "--timeout", "1")
    assert clean_error(r) and "time limit" in r.output and "--timeout" in r.output
    for bad in ("0", "-1", "nan", "inf", "1e9"):
        r = invoke("query", path, "RETURN 1 AS a", "--timeout", bad)
        assert clean_error(r) and "--timeout must be" in r.output, (bad, r.output)


def test_what_kuzu_cannot_interrupt_is_stopped_by_time_or_memory(bank):
    path, _ = bank
    huge = "RETURN size(rpad('', 2000000000, 'x')) AS n"  # one value: Kùzu checks its time limit between batches
    assert run_query(path, "MATCH (e:Entity) RETURN count(e) AS n", participant="P09", memory_mb=600).frame["n"][0] > 0
    with pytest.raises(StoreError, match="more than 600 MB of memory"):
        run_query(path, huge, participant="P09", memory_mb=600)
    with pytest.raises(QueryTimeout, match="could not interrupt"):
        run_query(path, "RETURN size(rpad('', 150000000, 'x')) AS n", participant="P09", timeout=0.2, grace=0.3,
                  memory_mb=8192)


def test_a_kuzu_crash_is_an_error_not_a_dead_caller(bank):
    path, _ = bank
    before = digest(path)
    # what the guard refuses (Kùzu 0.11.3 crashes on several statements), sent past it on purpose
    with pytest.raises(StoreError, match="Kùzu crashed \\(SIGSEGV\\)"):
        _in_child({"bank": str(path), "jobs": [{"participant": "P09", "db": str(path / "P09.kuzu"), "params": {},
                                                "counts": None}],
                   "cypher": "RETURN 1 AS a; RETURN 2 AS b", "write": False, "timeout": 30.0, "memory_mb": 2048,
                   "grace": 5.0, "max_rows": 10, "max_bytes": 2**20, "confine": True, "csv_fd": None})
    assert digest(path) == before


def test_damaged_text_in_a_database_is_an_error(bank):
    path, _ = bank
    db = path / "P09.kuzu"
    data = db.read_bytes()
    assert data.count(b"P09_103") > 10
    db.write_bytes(data.replace(b"P09_103", b"P09\xff103"))
    r = invoke("query", path, "MATCH (s:Segment) RETURN s.id AS id", "--participant", "P09")
    assert clean_error(r) and "does not match" in r.output  # the integrity check sees the edit first
    # past it, knowingly: Kùzu hands over the damaged bytes, and they are an error, not an answer
    r = invoke("query", path, "MATCH (s:Segment) RETURN s.id AS id", "--participant", "P09", "--no-verify")
    assert clean_error(r) and "not valid UTF-8" in r.output and "damaged" in r.output
    r = invoke("tool", path, "get_state_at_time", "100", "--participant", "P09", "--arg", "video", "P09_104",
               "--no-verify")
    assert clean_error(r) and "not valid UTF-8" in r.output
    r = invoke("run", path, "videos", "-p", "participant", "P09", "--no-verify")
    assert clean_error(r) and "not valid UTF-8" in r.output


PARENT_RUNS_A_LONG_READ = r"""
import sys
from memora_graph.adhoc import run_query
heavy = "UNWIND range(1, 100000) AS x UNWIND range(1, 100000) AS y WITH x, y WHERE (x * y) % 7 = 3 RETURN count(*) AS n"
run_query(sys.argv[1], heavy, participant="P09", timeout=120)
"""


def _children(pid: int) -> list[int]:
    """The ad-hoc query processes `pid` started (not the integrity probes it may also start)."""
    import os

    kids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    ppid = int(fh.read().split(") ")[-1].split()[1])
                with open(f"/proc/{entry}/cmdline", "rb") as fh:
                    if ppid == pid and b"memora_graph.adhoc" in fh.read():
                        kids.append(int(entry))
            except (OSError, ValueError, IndexError):
                pass
    return kids


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_read_query_goes_with_a_killed_caller(bank):
    """A server killed with kill -9 while an ad-hoc read ran must not leave the query process
    holding the database open (the next writer would find the participant busy)."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    path, _ = bank
    root = Path(__file__).resolve().parents[3]
    caller = subprocess.Popen([sys.executable, "-c", PARENT_RUNS_A_LONG_READ, str(path)],
                              env={**os.environ, "PYTHONPATH": str(root)})
    deadline = time.monotonic() + 60
    kids: list[int] = []
    while not kids and time.monotonic() < deadline and caller.poll() is None:
        kids = _children(caller.pid)
        time.sleep(0.1)
    assert kids, "the caller never started its query process"
    time.sleep(3.0)  # the child is past its start-up (and its request to die with its parent)
    os.kill(caller.pid, signal.SIGKILL)
    caller.wait()
    alive = lambda pid: os.path.exists(f"/proc/{pid}") and open(f"/proc/{pid}/stat").read().split(") ")[-1][0] != "Z"
    deadline = time.monotonic() + 15
    while any(alive(k) for k in kids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [k for k in kids if alive(k)]
    for k in left:
        os.kill(k, signal.SIGKILL)
    assert not left, "the query process outlived its killed caller"
    # and the participant answers again
    assert run_query(path, "MATCH (e:Entity) RETURN count(e) AS n", participant="P09", write=False).frame["n"][0] > 0

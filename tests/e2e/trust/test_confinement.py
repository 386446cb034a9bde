"""Issue 20: the kernel, not only the read guard, keeps an ad-hoc query to its one database.

With the guard switched off (MEMORA_TEST_NO_GUARD, test-only) every escape class still fails in
the confined child: reading a file outside the bank, reading another participant's database,
writing a file, loading an extension, attaching a database, the network. The two repro
commands of the issue fail through the CLI and through the MCP `cypher` tool. Results are
capped; the MCP tool runs at most 2 children at once. Where the kernel has no Landlock
(MEMORA_TEST_NO_LANDLOCK simulates it) the CLI warns and `memora serve` offers no `cypher`."""

from __future__ import annotations

import json
import os
import shutil
import sys
import threading
from pathlib import Path

import anyio
import pytest
from click.testing import CliRunner
from mcp import Client, StdioServerParameters

import memora_graph.adhoc as adhoc
from memora_graph.adhoc import run_query
from memora_graph.cli import main
from memora_graph.confine import NO_GUARD_ENV, NO_LANDLOCK_ENV, mode
from memora_graph.errors import QueryRefused, StoreError
from memora_graph.serve import MemoryService
from support.bankfiles import file_sha256
from memora_graph.cli.perf.serve import ServerProcess
from memora_graph.serve.service import Busy

pytestmark = pytest.mark.skipif(not mode().confined, reason="this kernel offers no Landlock: " + mode().why)

SECRET = "not-for-memora-7f3a"


def invoke(*args, env=None):
    return CliRunner().invoke(main, [str(a) for a in args], env=env)


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): file_sha256(p)
            for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != ".verified.json" and ".cache" not in p.parts}  # caches a server writes


@pytest.fixture()
def bank(small_bank, tmp_path):
    path = tmp_path / "bank"
    shutil.copytree(small_bank[0], path)
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "secret.csv").write_text(f"a,b\n{SECRET},1\n")
    (out / "evil.kuzu_extension").write_bytes(b"\x7fELF not really")
    return path, out


def escapes(path: Path, out: Path) -> list[tuple[str, str]]:
    """(class, statement): each is refused by the guard; here it goes past it to Kùzu."""
    secret = out.parent / "secret.csv"
    return [
        ("read a file outside the bank", f"LOAD FROM '{secret}' (header=true) RETURN *"),
        ("read a file outside the bank", "LOAD FROM '/etc/passwd' (file_format='csv', header=false, delim=':') "
                                         "RETURN *"),
        ("read a file outside the bank", "UNWIND [1] AS AS LOAD FROM '/etc/passwd' (file_format='csv', "
                                         "header=false, delim=':') RETURN *"),
        ("read a file of the bank", f"LOAD FROM '{path}/manifest.json' RETURN *"),
        ("read another participant", f"LOAD FROM '{path}/P37.kuzu' (file_format='csv', header=false) RETURN * "
                                     "LIMIT 3"),
        ("read another participant", f"ATTACH '{path}/P37.kuzu' AS o (dbtype kuzu)"),
        ("write a file", f"COPY (MATCH (e:Entity) RETURN e.name AS n) TO '{out}/leak.csv'"),
        ("write a file", f"COPY (RETURN 'x' AS a) TO '{path}/manifest.json'"),
        ("write a file", f"EXPORT DATABASE '{out}/export'"),
        ("load an extension", f"LOAD EXTENSION '{out}/evil.kuzu_extension'"),
        ("attach", f"ATTACH '{out}/new.kuzu' AS n (dbtype kuzu)"),
        ("network", "LOAD FROM 'http://127.0.0.1:9/x.csv' RETURN *"),
        ("install an extension", "INSTALL httpfs"),
    ]


def test_with_the_guard_off_the_kernel_stops_every_escape(bank, monkeypatch):
    path, out = bank
    before = digest(path)
    monkeypatch.setenv(NO_GUARD_ENV, "1")
    failures = []
    for kind, text in escapes(path, out):
        for write in (False, True):
            try:
                result = run_query(path, text, participant="P09", write=write)
            except (StoreError, QueryRefused) as exc:
                said = str(exc)
                if "root:" in said or SECRET in said:
                    failures.append((kind, write, "leaked in the error", said[:200]))
            else:
                failures.append((kind, write, "ran", result.frame.head(3).to_dicts()))
    assert failures == []
    assert [p.name for p in out.iterdir()] == ["evil.kuzu_extension"]  # nothing written, nothing created
    after = digest(path)
    # a --write child opens P09 read-write and checkpoints it on close: its bytes (and the hash the
    # manifest records for them) may change, its rows do not; nothing else in the bank changes
    moved = {"P09.kuzu", "manifest.json"}
    assert {k: v for k, v in after.items() if k not in moved} == {k: v for k, v in before.items() if k not in moved}
    r = invoke("verify", path)
    assert r.exit_code == 0, r.output
    assert not [p for p in path.iterdir() if p.name.startswith(adhoc.WORK_PREFIX)]  # private folders removed


def test_the_issue_repros_fail_through_the_cli_and_mcp(bank):
    path, _ = bank
    from memora_graph.retrieve.view import persist_bank

    persist_bank(path, ["P37"])  # the tool stores the issue read P37's (there P09's) rows from
    cache = sorted((path / ".cache").rglob("rows*.json"))
    assert cache
    repros = ["UNWIND [1] AS AS LOAD FROM '/etc/passwd' (file_format='csv', header=false, delim=':') RETURN *",
              f"UNWIND [1] AS AS LOAD FROM '{cache[0]}' RETURN * LIMIT 3"]
    for text in repros:
        for extra in ([], ["--write"]):
            r = invoke("query", path, text, "--participant", "P09", *extra)
            assert r.exit_code == 1 and r.output.startswith("Error: refused") and "root:" not in r.output, r.output
    before = digest(path)
    server = ServerProcess(path, "P09")
    try:
        async def run() -> None:
            async with Client(server.url) as client:
                for text in repros:
                    res = await client.call_tool("cypher", {"query": text})
                    assert res.is_error and "refused" in res.content[0].text and "root:" not in res.content[0].text
                    assert res.structured_content is None
        anyio.run(run)
    finally:
        server.stop()

    async def over_stdio() -> None:
        params = StdioServerParameters(command=sys.executable, args=["-m", "memora_graph.cli", "serve", str(path),
                                                                     "--participant", "P09"],
                                       env={"PYTHONPATH": str(Path(__file__).resolve().parents[3])})
        async with Client(params) as client:
            for text in repros:
                res = await client.call_tool("cypher", {"query": text})
                assert res.is_error and "refused" in res.content[0].text and "root:" not in res.content[0].text
    anyio.run(over_stdio)
    assert digest(path) == before


def test_caps_on_a_cartesian_product(bank):
    path, _ = bank
    product = "MATCH (a:StateEvent), (b:StateEvent) RETURN a.id AS a, b.id AS b"
    r = invoke("query", path, product, "--participant", "P37", "--max-rows", "50", "--json")
    assert r.exit_code == 0, r.output
    rows = json.loads(r.stdout)
    assert len(rows) == 50
    assert "notice: result cut to its first 50 of" in r.stderr and "SKIP" in r.stderr and "--csv" in r.stderr
    result = run_query(path, product, participant="P37")  # the default cap
    assert result.frame.height == adhoc.MAX_ROWS and result.cut == "rows" and result.total_rows > adhoc.MAX_ROWS
    result = run_query(path, product, participant="P37", max_bytes=20_000)
    assert result.cut == "bytes" and 0 < result.frame.height < adhoc.MAX_ROWS
    assert len(adhoc._ipc(result.frame)) <= 20_000
    small = run_query(path, "MATCH (e:Entity) RETURN count(*) AS n", participant="P37")
    assert small.cut is None and small.notice is None


def test_csv_streams_every_row_past_the_cap(bank, tmp_path):
    path, _ = bank
    import subprocess

    out = tmp_path / "all.csv"
    root = Path(__file__).resolve().parents[3]
    with open(out, "w") as fh:
        res = subprocess.run([sys.executable, "-m", "memora_graph.cli", "query", str(path),
                              "MATCH (a:StateEvent), (b:StateEvent) RETURN a.id AS a, b.id AS b", "--participant",
                              "P37", "--max-rows", "10", "--csv"], stdout=fh, stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": str(root)})
    assert res.returncode == 0, res.stderr
    lines = out.read_text().splitlines()
    assert lines[0] == "a,b" and len(lines) - 1 > 10 and "notice" not in res.stderr


def test_mcp_cypher_calls_are_bounded(bank):
    path, _ = bank
    service = MemoryService(path, "P37", cypher_in_flight=2, cypher_queue=1)
    slow = "UNWIND range(1, 3000) AS x UNWIND range(1, 3000) AS y RETURN count(*) AS n"
    start = threading.Barrier(6)
    results: list[object] = []
    lock = threading.Lock()
    running = {"now": 0, "most": 0}
    real = adhoc._in_child

    def counted(request, csv_fd=None):
        with lock:
            running["now"] += 1
            running["most"] = max(running["most"], running["now"])
        try:
            return real(request, csv_fd)
        finally:
            with lock:
                running["now"] -= 1

    def call() -> None:
        start.wait()
        try:
            out: object = service.call("cypher", {"query": slow})
        except Busy as exc:
            out = exc
        with lock:
            results.append(out)

    adhoc._in_child = counted
    try:
        threads = [threading.Thread(target=call) for _ in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
    finally:
        adhoc._in_child = real
        service.close()
    busy = [r for r in results if isinstance(r, Busy)]
    done = [r for r in results if isinstance(r, dict)]
    assert len(results) == 6 and len(busy) == 3 and len(done) == 3, results
    assert all("busy" in str(b) for b in busy) and all(d["rows"] == [{"n": 9_000_000}] for d in done)
    assert running["most"] == 2


def test_without_landlock_the_cli_warns_and_serve_holds_back_cypher(bank, monkeypatch):
    path, _ = bank
    r = invoke("query", path, "RETURN 1 AS a", "--participant", "P09", "--json", env={NO_LANDLOCK_ENV: "1"})
    assert r.exit_code == 0 and "warning: unconfined" in r.stderr and json.loads(r.stdout) == [{"a": 1}]
    r = invoke("query", path, "RETURN 1 AS a", "--participant", "P09", "--json")
    assert r.exit_code == 0 and "warning" not in r.stderr
    r = invoke("verify", path)
    assert "ad-hoc Cypher (memora query, the cypher tool): kernel-confined (Landlock ABI" in r.stderr
    monkeypatch.setenv(NO_LANDLOCK_ENV, "1")
    r = invoke("verify", path)
    assert "ad-hoc Cypher (memora query, the cypher tool): unconfined" in r.stderr
    with MemoryService(path, "P09") as service:
        assert "cypher" not in [e.name for e in service.endpoints()]
    with MemoryService(path, "P09", unconfined_cypher=True) as service:
        assert "cypher" in [e.name for e in service.endpoints()]
        assert service.call("cypher", {"query": "RETURN 1 AS a"})["rows"] == [{"a": 1}]
    with pytest.raises(QueryRefused, match="unconfined"):
        run_query(path, "RETURN 1 AS a", participant="P09", require_confinement=True)


def test_serve_reports_the_mode_when_it_starts(bank):
    """The mode depends on the machine, so it is said when the server starts (and by verify), not in
    the help text, which the CLI reference is generated from."""
    import subprocess

    path, _ = bank
    root = Path(__file__).resolve().parents[3]
    for env, says in (({}, "ad-hoc Cypher kernel-confined (Landlock ABI"), ({NO_LANDLOCK_ENV: "1"}, "ad-hoc Cypher unconfined")):
        res = subprocess.run([sys.executable, "-m", "memora_graph.cli", "serve", str(path), "--participant", "P09"],
                             stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300,
                             env={**os.environ, "PYTHONPATH": str(root), **env})
        assert res.returncode == 0 and says in " ".join(res.stderr.split()), res.stderr
    res = subprocess.run([sys.executable, "-m", "memora_graph.cli", "serve", "--help"], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(root)})
    assert "--unconfined-cypher" in res.stdout and "memora verify" in " ".join(res.stdout.split())


def test_the_child_speaks_json_and_arrow_not_pickle():
    source = Path(adhoc.__file__).read_text()
    assert "pickle" not in source

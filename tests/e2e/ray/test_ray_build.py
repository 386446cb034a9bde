"""The Ray executor on a local Ray instance with 2 CPUs (`pytest -m ray`, after pip install -e '.[dev,ray]'):
a build of three small participants is the local build (counts, ids, decision mix, manifest
entries), a failing task is retried then reported with the bank left consistent, a killed driver
resumes, and `memora consolidate --executor ray` (finished files through --ray-shared) is the local one."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

from memora_graph.bank import Bank
from memora_graph.cli import main
from memora_graph.executors import Executor, TasksFailed
from memora_graph.pipeline import build_bank

pytestmark = pytest.mark.ray

THREE = ["P09", "P23", "P37"]  # the three smallest participants of the bundled annotations
MEMORA = [sys.executable, "-m", "memora_graph.cli"]
IDS = {  # every record id a build writes, per table
    "Segment": "MATCH (x:Segment) RETURN x.id AS id ORDER BY id",
    "Entity": "MATCH (x:Entity) RETURN x.id AS id ORDER BY id",
    "StateEvent": "MATCH (x:StateEvent) RETURN x.id AS id ORDER BY id",
    "Place": "MATCH (x:Place) RETURN x.id AS id ORDER BY id",
    "EditOp": "MATCH (x:EditOp) RETURN x.id AS id ORDER BY id",
    "Routine": "MATCH (x:Routine) RETURN x.id AS id ORDER BY id",
    "Preference": "MATCH (x:Preference) RETURN x.id AS id ORDER BY id",
}
DECISIONS = "MATCH (x:EditOp) RETURN x.op AS op, count(*) AS n ORDER BY op"


@pytest.fixture(scope="module")
def local_three(tmp_path_factory):
    path = tmp_path_factory.mktemp("local") / "bank"
    return path, build_bank(path, THREE, jobs=1)


def _ids(bank, p) -> dict:
    with Bank(bank).open(p) as store:
        out = {t: store.query(q)["id"].to_list() for t, q in IDS.items()}
        out["decisions"] = store.query(DECISIONS).rows()
    return out


def _entry(bank, p) -> dict:
    entry = json.loads(json.dumps(Bank(bank).manifest()["participants"][p]))
    integ = entry.pop("integrity")
    entry["tables"] = integ["tables"]  # rows per table; the file's hash and time differ between builds
    # the records of derived files (bank/derived.py) name the database hash they were computed from,
    # and are written by whichever process first computes them: bookkeeping, not the bank's content
    entry.pop("derived", None)
    return entry


def assert_same_bank(got, want, participants=THREE):
    a, b = Bank(got).manifest(), Bank(want).manifest()
    assert sorted(a["participants"]) == sorted(participants) and "writing" not in a
    for k in ("mode", "embed_model", "consolidated", "condition", "indexes"):
        assert a.get(k) == b.get(k), k
    for p in participants:
        assert _entry(got, p) == _entry(want, p), p
        assert _ids(got, p) == _ids(want, p), p
    assert not (got / ".staging").exists() and not list(got.glob(".*incoming*"))
    r = CliRunner().invoke(main, ["verify", str(got)])
    assert r.exit_code == 0, r.output


def test_a_ray_build_is_the_local_build(ray_local, local_three, tmp_path):
    want, local = local_three
    seen = []
    res = build_bank(tmp_path / "bank", THREE, executor=Executor("ray"), on_video=lambda p, v, n: seen.append((p, v)))
    assert [r.participant for r in res.participants] == THREE
    for a, b in zip(res.participants, local.participants):
        assert (a.counts, a.decisions, a.videos_built, a.segments) == (b.counts, b.decisions, b.videos_built, b.segments)
    assert sorted(seen) == sorted(set(seen)) and len(seen) == sum(r.videos_built for r in local.participants)
    assert res.model_seconds > 0 and res.embedding_seconds > 0
    assert_same_bank(tmp_path / "bank", want)


def test_a_failing_task_is_retried_then_reported_and_the_bank_stays_consistent(ray_local, local_three, tmp_path):
    want, _ = local_three
    bank = tmp_path / "bank"
    notices = []
    # P09 fails on every attempt: tried 1 + 1 times, reported; P37 is built and installed
    with pytest.raises(TasksFailed) as err:
        build_bank(bank, ["P09", "P37"], executor=Executor("ray", retries=1, fail_attempts={"P09": 99}),
                   on_notice=notices.append)
    assert err.value.failed.keys() == {"P09"} and "P09 failed on all 2 attempt(s)" in str(err.value)
    assert "injected failure" in str(err.value) and "the other 1 were built and installed" in str(err.value)
    assert [n for n in notices if n.startswith("P09: attempt 1 failed")]
    data = Bank(bank).manifest()
    assert sorted(data["participants"]) == ["P37"] and "writing" not in data
    assert not Bank(bank).db_path("P09").exists() and not (bank / ".staging").exists()
    assert_same_bank(bank, want, ["P37"])
    # the same command again, P09 failing once only: retried, then built; the bank is the local one
    notices.clear()
    build_bank(bank, ["P09", "P37"], executor=Executor("ray", retries=1, fail_attempts={"P09": 1}),
               on_notice=notices.append)
    assert [n for n in notices if n.startswith("P09: attempt 1 failed")]
    assert_same_bank(bank, want, ["P09", "P37"])


def test_a_killed_driver_resumes(ray_local, local_three, tmp_path):
    want, _ = local_three
    bank = tmp_path / "bank"
    cmd = [*MEMORA, "build", str(bank), "--participants", ",".join(THREE), "--executor", "ray", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 300
    installed: list = []
    while time.time() < deadline and proc.poll() is None:
        try:
            installed = list(Bank(bank).manifest()["participants"])
        except Exception:  # noqa: BLE001 - not created yet
            installed = []
        if installed:
            break
        time.sleep(0.05)
    assert proc.poll() is None and 0 < len(installed) < len(THREE), "the build ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    time.sleep(3)
    # what it installed is complete and recorded; the rest is not in the bank
    assert_same_bank(bank, want, installed)
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert_same_bank(bank, want)
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # whatever of its Ray instance outlived it
    except ProcessLookupError:
        pass


def test_consolidate_on_ray_is_the_local_consolidate(ray_local, local_three, tmp_path):
    want, _ = local_three
    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(want, a)
    shutil.copytree(want, b)
    local = CliRunner().invoke(main, ["consolidate", str(a), "--participants", "P09,P37", "--json", "--quiet"])
    shared = tmp_path / "shared"  # finished databases come back through a shared path instead of the object store
    on_ray = CliRunner().invoke(main, ["consolidate", str(b), "--participants", "P09,P37", "--json", "--quiet",
                                       "--executor", "ray", "--ray-shared", str(shared)])
    assert local.exit_code == 0 and on_ray.exit_code == 0, on_ray.output
    strip = lambda out: [{k: v for k, v in r.items() if k != "seconds"} for r in json.loads(out)]  # noqa: E731
    assert strip(on_ray.output) == strip(local.output)
    assert shared.is_dir() and not list(shared.iterdir())  # each file was moved into the bank
    for p in ("P09", "P37"):
        assert _entry(b, p) == _entry(a, p) and _ids(b, p) == _ids(a, p)
    assert CliRunner().invoke(main, ["verify", str(b)]).exit_code == 0

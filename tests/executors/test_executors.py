"""The executor settings without Ray: `local` stays the default, and `--executor ray` without the
[ray] extra says how to install it (these run in every test run, Ray or not)."""

from __future__ import annotations

import sys

import pytest
from click.testing import CliRunner

from memora_graph.cli import main
from memora_graph.errors import MemoraError
from memora_graph.executors import Executor, make_executor, split_urls


def test_local_is_the_default_and_takes_no_ray_settings():
    ex = make_executor(None)
    assert ex.name == "local" and not ex.remote
    with pytest.raises(MemoraError, match="--ray-address applies with --executor ray"):
        Executor("local", address="auto")
    with pytest.raises(MemoraError, match="spread over Ray tasks"):
        make_executor("local", base_url="http://127.0.0.1:8000/v1,http://127.0.0.1:8001/v1")
    with pytest.raises(MemoraError, match="one of local, ray"):
        Executor("dask")


def test_base_urls_are_spread_over_tasks(monkeypatch):
    assert split_urls(" http://a/v1, http://b/v1 ,") == ["http://a/v1", "http://b/v1"]
    ex = Executor("ray", base_urls=split_urls("http://a/v1,http://b/v1"))
    assert [ex.base_url(i) for i in range(4)] == ["http://a/v1", "http://b/v1", "http://a/v1", "http://b/v1"]
    assert Executor("ray").base_url(3) is None


@pytest.mark.parametrize("args", [
    ["build", "{bank}", "--participants", "P09"],
    ["consolidate", "{bank}"],
    ["bench", "run", "{bank}", "--out", "{out}"],
])
def test_executor_ray_without_ray_says_how_to_install_it(monkeypatch, tmp_path, args):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError, as without the extra
    bank = tmp_path / "bank"
    bank.mkdir()
    r = CliRunner().invoke(main, [a.format(bank=bank, out=tmp_path / "out") for a in args] + ["--executor", "ray"])
    assert r.exit_code != 0
    assert "pip install -e '.[ray]'" in r.output and "--executor ray needs Ray" in r.output
    assert not (bank / "manifest.json").exists()


def test_install_names_the_incoming_database_only_once_it_is_whole(small_bank, tmp_path, monkeypatch):
    """The driver's install of a handed-back database (executors/bundle.py, no Ray needed): a
    killed earlier driver's leftover is removed, the file being written has no name in the bank
    (Linux O_TMPFILE) until it is complete and hashed, and a damaged transfer changes nothing."""
    import hashlib
    import os
    import shutil

    from memora_graph.bank import Bank
    from memora_graph.errors import BankError
    from memora_graph.executors import bundle

    path = tmp_path / "bank"
    shutil.copytree(small_bank[0], path)
    bank = Bank(path)
    sealed = bundle.seal(bank, "P37")  # the bank's own finished participant, as a task would hand it back
    before = bank.db_path("P37").read_bytes()
    (path / ".P37.kuzu.incoming-999999").write_bytes(b"half a database from a killed driver")
    seen = []
    digest = hashlib.file_digest

    def watching(fh, name):  # hashing happens after the whole file is written: is it named yet?
        seen.append(sorted(p.name for p in path.glob(".*incoming*")))
        return digest(fh, name)

    monkeypatch.setattr(hashlib, "file_digest", watching)
    update = bank.update_manifest

    def recording(change):  # the unfinished-build mark is written before the rename: named yet?
        seen.append(sorted(p.name for p in path.glob(".*incoming*")))
        return update(change)

    monkeypatch.setattr(bank, "update_manifest", recording)
    with pytest.raises(BankError, match="does not match the hash"):
        blob = bytearray(sealed["bytes"])
        blob[len(blob) // 2] ^= 0xFF  # one byte damaged in transfer
        bundle.install(bank, "P37", {**sealed, "bytes": bytes(blob)})
    assert bank.db_path("P37").read_bytes() == before and not list(path.glob(".*incoming*"))
    bundle.install(bank, "P37", sealed)
    assert bank.db_path("P37").read_bytes() == before and not list(path.glob(".*incoming*"))
    if getattr(os, "O_TMPFILE", 0):
        assert seen[:3] == [[], [], []]  # unnamed while written, hashed and marked in the manifest
    r = CliRunner().invoke(main, ["verify", str(path)])
    assert r.exit_code == 0, r.output

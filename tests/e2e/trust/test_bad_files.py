"""Issue 20, points 3 and 4: a database that is a folder, a link, a device or missing is reported
by `memora verify` and refused by every reader; the eight tracebacks of the attack corpus are
clear errors naming the file and the field."""

from __future__ import annotations

import json
import os
import re
import shutil

import pytest
from click.testing import CliRunner

from memora_graph.cli import main


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def clean_error(r) -> bool:
    return r.exit_code == 1 and "Error: " in r.output and (r.exception is None or isinstance(r.exception, SystemExit))


READERS = [("query", "MATCH (e:Entity) RETURN count(*) AS n", "--participant", "P09"),
           ("stats", "--participant", "P09"),
           ("tool", "search", "plate", "--participant", "P09"),
           ("run", "videos", "-p", "participant", "P09")]


@pytest.fixture()
def bank(small_bank, tmp_path):
    path = tmp_path / "bank"
    shutil.copytree(small_bank[0], path)
    return path


@pytest.mark.parametrize("damage", ["folder", "symlink to a copy outside", "symlink to /dev/zero", "missing"])
def test_verify_reports_and_readers_refuse_a_database_that_is_not_a_file(bank, tmp_path, damage):
    db = bank / "P09.kuzu"
    outside = tmp_path / "outside.kuzu"
    shutil.copy(db, outside)
    db.unlink()
    if damage == "folder":
        db.mkdir()
    elif damage == "symlink to a copy outside":
        db.symlink_to(outside)
    elif damage == "symlink to /dev/zero":
        db.symlink_to("/dev/zero")
    r = invoke("verify", bank)
    assert r.exit_code == 1 and "problems found" in r.output, r.output
    said = {"folder": "is a folder", "missing": "missing"}.get(damage, "is a symbolic link")
    assert re.search(rf"P09: .*P09\.kuzu: .*{said}", r.output), r.output
    assert "P37: " not in r.output  # the other participant is fine
    for args in READERS:
        r = invoke(args[0], bank, *args[1:])
        assert clean_error(r) and "P09.kuzu" in r.output, (args, r.output)
    before = outside.read_bytes()
    r = invoke("query", bank, "CREATE (:Participant {id: 'X1', participant: 'X1'})", "--participant", "P09", "--write")
    assert clean_error(r) and "P09.kuzu" in r.output
    assert outside.read_bytes() == before  # --write never reached the copy outside the bank


def test_a_manifest_whose_writing_is_text_is_an_error_for_every_command(bank):
    data = json.loads((bank / "manifest.json").read_text())
    data["writing"] = "P09"
    (bank / "manifest.json").write_text(json.dumps(data))
    for args in [("verify",), *READERS]:
        r = invoke(args[0], bank, *args[1:])
        assert clean_error(r) and "manifest.json" in r.output and "'writing'" in r.output, (args, r.output)


def test_a_damaged_tool_store_whose_hash_was_updated_is_read_around(bank):
    r = invoke("tool", bank, "search_objects", "plate", "--participant", "P09", "--json")
    assert r.exit_code == 0, r.output
    store = bank / ".cache" / "tools-P09"
    npy = sorted(store.glob("vectors-*.npy"))[0]
    npy.write_bytes(npy.read_bytes()[:200])  # truncated
    meta = json.loads((store / "meta.json").read_text())
    import hashlib

    meta["files"][npy.name] = hashlib.sha256(npy.read_bytes()).hexdigest()  # and its record "fixed" by hand
    (store / "meta.json").write_text(json.dumps(meta))
    r = invoke("tool", bank, "search_objects", "plate", "--participant", "P09", "--json")
    assert r.exit_code == 0 and r.exception is None, r.output
    assert json.loads(r.stdout)["results"]  # answered from the database instead
    r = invoke("verify", bank)
    assert r.exception is None or isinstance(r.exception, SystemExit)


@pytest.fixture()
def export(bank, tmp_path):
    out = tmp_path / "P09.json"
    r = invoke("export", bank, "--participant", "P09", "--out", out)
    assert r.exit_code == 0, r.output
    return json.loads(out.read_text())


def bad_exports(doc: dict) -> dict[str, tuple[object, str]]:
    """name -> (document or raw text, what the error must name)."""
    out: dict[str, tuple[object, str]] = {}
    d = json.loads(json.dumps(doc))
    d["manifest"]["counts"] = {k: str(v) for k, v in d["manifest"]["counts"].items()}
    out["counts as strings"] = (d, "manifest.counts.")
    out["nested 200,000 deep"] = ("[" * 200_000 + "]" * 200_000, "nested too deep")
    d = json.loads(json.dumps(doc))
    for t in d["tables"]:
        j = next((j for j, (_, typ) in enumerate(t["columns"]) if re.fullmatch(r"FLOAT\[\d+\]", typ)), None)
        if j is not None and t["data"]:
            col = t["columns"][j][0]
            t["data"][0][j] = t["data"][0][j][:10]
            break
    out["an embedding of the wrong length"] = (d, f"column {col}: 10 values")
    d = json.loads(json.dumps(doc))
    d["participant"] = "P09\n"
    out["a participant with a newline"] = (d, "field 'participant'")
    d = json.loads(json.dumps(doc))
    d["participant"] = "../P09"
    out["a participant with a path"] = (d, "field 'participant'")
    d = json.loads(json.dumps(doc))
    d["manifest"] = "x"
    out["manifest text"] = (d, "field 'manifest'")
    return out


def test_bad_exports_are_clear_errors_and_import_nothing(export, tmp_path):
    for name, (doc, says) in bad_exports(export).items():
        f = tmp_path / f"bad-{len(os.listdir(tmp_path))}.json"
        f.write_text(doc if isinstance(doc, str) else json.dumps(doc))
        target = tmp_path / "target"
        r = invoke("import", target, f)
        assert clean_error(r) and str(f) in r.output and says in r.output, (name, r.output)
        assert not target.exists() or not any(target.glob("*.kuzu")), name
        assert not [p for p in tmp_path.rglob("*") if "\n" in p.name], name


def test_participant_ids_are_refused_where_they_enter(bank):
    for bad in ("P09\n", "P0/9", "../P09", "P09\x00", "P 09"):
        for args in (("forget", bank, "--participant", bad), ("query", bank, "RETURN 1 AS a", "--participant", bad),
                     ("serve", bank, "--participant", bad)):
            r = invoke(*args)
            assert r.exit_code in (1, 2) and "Error" in r.output, (args, r.output)
            assert r.exception is None or isinstance(r.exception, SystemExit), (args, r.exception)
    assert sorted(p.name for p in bank.glob("*.kuzu")) == ["P09.kuzu", "P37.kuzu"]


def test_a_write_refused_on_counts_that_differ_records_nothing(bank):
    data = json.loads((bank / "manifest.json").read_text())
    data["participants"]["P09"]["counts"]["segments"] += 1  # a manifest edited by hand
    (bank / "manifest.json").write_text(json.dumps(data))
    r = invoke("query", bank, "CREATE (:Participant {id: 'X1', participant: 'X1'})", "--participant", "P09", "--write")
    assert clean_error(r) and "does not match" in r.output, r.output
    after = json.loads((bank / "manifest.json").read_text())
    assert after["participants"]["P09"]["counts"] == data["participants"]["P09"]["counts"]  # not "accepted"
    assert "writing" not in after
    assert not [p for p in bank.iterdir() if p.name.startswith(".adhoc-write-")]

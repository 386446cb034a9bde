"""The bank's lifecycle: staging that carries no code and is checked before it is loaded,
forgetting a person, rebuilding a participant whose annotations changed, and one source for
the tables' columns."""

from __future__ import annotations

import dataclasses
import json
import pickle
import shutil

import polars as pl
import pytest
from support.corrupt import memora

from memora_graph import schema
from memora_graph.bank import Bank
from memora_graph.errors import BankError, DataError, StoreError
from memora_graph.form.build import ParticipantBuilder
from memora_graph.form.editor import EntityState
from memora_graph.form.environment import PlaceState
from memora_graph.form.staging import Staging
from memora_graph.paths import epic_dir
from memora_graph.perceive.annotations import load_annotations
from memora_graph.pipeline import build_bank


def _clean(small_bank, p="P09"):
    return next(r for r in small_bank[1].participants if r.participant == p)


def _stage_without_finishing(path, embedder, epic_meta, videos: int, p: str = "P09") -> Staging:
    """What a build killed after `videos` videos leaves: staged videos, no database."""
    classes, durations = epic_meta
    bank = Bank(path)
    bank.init(mode="edited", embed_model=embedder.name, consolidated=False)
    df = load_annotations(None, participants=[p])
    with bank.participant_lock(p):
        builder = ParticipantBuilder(bank, p, embedder)
        for v in sorted(df["video_id"].unique().to_list())[:videos]:
            builder.build_video(v, df.filter(pl.col("video_id") == v).to_dicts(), durations[v], classes)
        builder.close()
    return builder.staging


class Planted:
    """Unpickling this creates a file: the proof that a pickle was loaded."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_staging_holds_no_pickles_and_a_planted_one_is_never_loaded(small_bank, embedder, epic_meta, tmp_path):
    path = tmp_path / "bank"
    staging = _stage_without_finishing(path, embedder, epic_meta, videos=2)
    staged = staging.entries()
    assert [s.name for s in staged] == ["0000_P09_103", "0001_P09_104"]
    kinds = {f.suffix for s in staged for f in s.iterdir()}
    assert kinds == {".arrow", ".json"}  # Arrow IPC and JSON only: no format that runs code
    marker = tmp_path / "pwned"
    (staging.root / "0002_P09_105.pkl").write_bytes(pickle.dumps(Planted(marker)))  # the old staging format
    (staged[1] / "Segment.arrow").write_bytes(pickle.dumps(Planted(marker)))  # swapped into a staged video
    v = memora("verify", path, "--json")
    assert v.returncode == 1 and "0002_P09_105.pkl: not a staged video" in v.stdout + v.stderr
    resumed = build_bank(path, ["P09"]).participants[0]
    assert not marker.exists()
    assert resumed.videos_skipped == 1  # 0000 loaded; 0001 failed its check and was built again
    clean = _clean(small_bank)
    assert resumed.counts == clean.counts and resumed.decisions == clean.decisions
    assert (staging.root / "0002_P09_105.pkl").exists()  # never opened, never hidden: verify still lists it


def test_a_damaged_staged_video_is_built_again_with_those_after_it(small_bank, embedder, epic_meta, tmp_path):
    path = tmp_path / "bank"
    staging = _stage_without_finishing(path, embedder, epic_meta, videos=3)
    second = staging.entries()[1]
    data = bytearray((second / "StateEvent.arrow").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (second / "StateEvent.arrow").write_bytes(bytes(data))
    assert "StateEvent.arrow does not match the sha256" in Staging.check(second)
    resumed = build_bank(path, ["P09"]).participants[0]
    assert resumed.videos_skipped == 1  # the third was edited on top of the second: rebuilt too
    clean = _clean(small_bank)
    assert resumed.counts == clean.counts and resumed.decisions == clean.decisions
    assert not staging.root.exists()


def test_forget_removes_every_trace_of_one_person(bank):
    cache = bank / ".cache"
    cache.mkdir(exist_ok=True)
    for name in ("graph2d-P09-1a2b.json", "graph2d-P09-1a2b.npy", "graph2d-P37-9f9f.json", "embeddings-MiniLM.npz"):
        (cache / name).write_bytes(b"x")
    (bank / ".staging" / "P09" / "0000_P09_103").mkdir(parents=True)
    (bank / "P09.kuzu.wal").write_bytes(b"x")
    r = memora("forget", bank, "--participant", "P09", "--yes")
    assert r.returncode == 0, r.stdout + r.stderr
    for what in ("P09.kuzu", "P09.kuzu.wal", ".staging/P09", "graph2d-P09-1a2b.json", "graph2d-P09-1a2b.npy",
                 "embeddings-MiniLM.npz", "manifest.json: entry P09"):
        assert what in r.stdout, what
    left = sorted(str(p.relative_to(bank)) for p in bank.rglob("*"))
    assert not [x for x in left if "P09" in x], left
    assert (cache / "graph2d-P37-9f9f.json").exists()
    data = json.loads((bank / "manifest.json").read_text())
    assert list(data["participants"]) == ["P37"] and "P09" not in json.dumps(data["participants"])
    assert memora("verify", bank).returncode == 0  # what remains is whole
    again = memora("forget", bank, "--participant", "P09", "--yes")
    assert again.returncode == 1 and "nothing of P09" in again.stdout + again.stderr
    dry = memora("forget", bank, "--participant", "P09", "--dry-run")  # a dry run of nobody says so too
    assert dry.returncode == 1 and "nothing of P09 in" in dry.stderr and "(the bank has: P37)" in dry.stderr


def test_forget_asks_first_and_refuses_without_a_terminal(bank):
    import os
    import pty
    import subprocess
    import sys

    from support.corrupt import ROOT

    piped = memora("forget", bank, "--participant", "P09")  # stdin is not a terminal: nobody to ask
    assert piped.returncode == 1 and "stdin is not a terminal" in piped.stderr and "--yes" in piped.stderr
    assert (bank / "P09.kuzu").exists()

    def answer(reply: str) -> tuple[int, str]:
        """The command on a terminal (a pseudo-terminal), answering its question with `reply`."""
        main, child = pty.openpty()
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
        env.pop("MEMORA_NO_VERIFY", None)
        proc = subprocess.Popen([sys.executable, "-m", "memora_graph.cli", "forget", str(bank), "--participant", "P09"],
                                stdin=child, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
        os.close(child)
        os.write(main, reply.encode())
        out = proc.communicate(timeout=120)[0].decode()
        os.close(main)
        return proc.returncode, out

    code, out = answer("n\n")
    assert code == 1 and "would remove" in out and "Remove every trace of P09" in out and "nothing of P09 was removed" in out
    assert (bank / "P09.kuzu").exists()
    code, out = answer("y\n")
    assert code == 0 and "removed " in out and not (bank / "P09.kuzu").exists()


def test_forget_waits_for_no_build(bank):
    b = Bank(bank)
    with b.participant_lock("P09"):
        r = memora("forget", bank, "--participant", "P09", "--yes")  # waits 10 s for the lock, then says why not
    assert r.returncode == 1 and "being built (or forgotten) by another process" in r.stdout + r.stderr
    assert (bank / "P09.kuzu").exists()


def _annotations_with_a_change(tmp_path, video: str) -> tuple:
    """The bundled annotations (and the tables beside them) with one narration of `video` changed."""
    folder = tmp_path / "epic"
    shutil.copytree(epic_dir(), folder, ignore=shutil.ignore_patterns("README.md", "*provenance*"))
    csv = folder / "extension_narrations.csv"
    df = pl.read_csv(csv, infer_schema=False)
    first = df.with_row_index().filter(pl.col("video_id") == video)["index"][0]
    df = df.with_columns(pl.when(pl.int_range(pl.len()) == first).then(pl.lit("wash plate"))
                         .otherwise(pl.col("narration")).alias("narration"))
    df.write_csv(csv)
    return csv, df.row(int(first), named=True)["narration_id"]


def test_changed_annotations_of_a_built_video_point_to_rebuild(bank, tmp_path):
    csv, _ = _annotations_with_a_change(tmp_path, "P09_104")
    before = (bank / "P09.kuzu").read_bytes()
    with pytest.raises(DataError, match=r"P09: P09_104\).*--rebuild P09_104"):
        build_bank(bank, ["P09"], annotations=csv)
    assert (bank / "P09.kuzu").read_bytes() == before  # nothing was touched
    old = Bank(bank).manifest()["participants"]["P09"]
    notes = []
    res = build_bank(bank, annotations=csv, rebuild=["P09_104"], on_notice=notes.append)
    assert [r.participant for r in res.participants] == ["P09"]  # only the participant that owns the video
    assert "rebuilding P09" in notes[0] and "sequential" in notes[0]
    new = Bank(bank).manifest()["participants"]["P09"]
    assert new["annotations"]["P09_104"] != old["annotations"]["P09_104"]
    assert new["annotations"]["P09_103"] == old["annotations"]["P09_103"]
    assert not (bank / ".trash").exists()
    with Bank(bank).open("P09") as s:
        said = s.query("MATCH (x:StateEvent) WHERE x.video = 'P09_104' RETURN x.narration AS n")["n"].to_list()
    assert "wash plate" in said
    build_bank(bank, ["P09"], annotations=csv)  # now in agreement: nothing to say


def test_a_failed_rebuild_puts_the_old_database_back(bank, tmp_path, monkeypatch):
    import memora_graph.pipeline.annotations as annotations

    before = (bank / "P09.kuzu").read_bytes()
    entry = Bank(bank).manifest()["participants"]["P09"]

    def boom(*a, **k):
        raise RuntimeError("simulated failure in the middle of the rebuild")

    monkeypatch.setattr(annotations, "build_one", boom)  # where build_bank looks it up
    with pytest.raises(RuntimeError, match="simulated"):
        build_bank(bank, rebuild=["P09"])
    assert (bank / "P09.kuzu").read_bytes() == before
    assert Bank(bank).manifest()["participants"]["P09"] == entry
    assert not (bank / ".trash").exists()
    Bank(bank).open("P09").close()


def test_rebuild_names_an_unknown_video(bank):
    with pytest.raises(DataError, match="--rebuild P99_101: no such video or participant"):
        build_bank(bank, rebuild=["P99_101"])


def test_one_source_per_table():
    entity = schema.columns("Entity")
    assert [f.name for f in dataclasses.fields(EntityState)] == entity  # the editor's record is the row
    assert [f.name for f in dataclasses.fields(PlaceState)] == schema.columns("Place", emb=False)
    assert schema.columns("Routine")[-3:] == ["source", "processor", "detail"]  # ALTER TABLE ... ADD, in order
    assert schema.table("SUPPORTED_BY").pairs == (("Routine", "Segment"), ("Preference", "Segment"))
    assert schema.table("IN_PLACE").names() == ["from", "to", "op", "is_primary", "zones"]
    with pytest.raises(StoreError, match="lacks column.*held_by"):
        schema.frame("Entity", [{c: None for c in entity if c not in ("held_by", "emb")}])


def test_copy_takes_only_generated_statements(tmp_path):
    from memora_graph.store import Store

    with Store(tmp_path / "P01.kuzu", read_only=False) as s:
        s.apply_schema()
        frame = pl.DataFrame({"from": ["a"], "to": ["b"]})
        with pytest.raises(StoreError, match="needs one of its FROM / TO pairs"):
            s.copy("SUPPORTED_BY", frame)  # two pairs: the pair must be named
        with pytest.raises(StoreError, match="no table 'Nope"):
            s.copy("Nope; DROP TABLE Entity", frame)
        with pytest.raises(StoreError, match="lacks column"):
            s.copy("Participant", pl.DataFrame({"id": ["P01"]}))
        s.copy("Participant", pl.DataFrame({"participant": ["P01"], "id": ["P01"]}))  # conformed: order, types
        assert s.query("MATCH (p:Participant) RETURN p.id AS id, p.participant AS participant").rows() == [("P01", "P01")]


def test_every_rw_open_records_the_integrity_again(bank):
    b = Bank(bank)
    before = b.manifest()["participants"]["P09"]["integrity"]
    with b.open("P09", read_only=False) as s:
        s.query("CREATE (:Participant {id: 'X99', participant: 'P09'})")
    after = b.manifest()["participants"]["P09"]["integrity"]
    assert after["sha256"] != before["sha256"] and after["tables"]["Participant"] == 2
    assert "writing" not in b.manifest()
    b.open("P09").close()


def test_a_rw_open_that_cannot_lock_leaves_no_mark(bank):
    import subprocess
    import sys

    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from memora_graph.store import Store; s = Store(sys.argv[1], read_only=False); "
        "print('ready', flush=True); time.sleep(30)"), str(bank / "P37.kuzu")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "ready"
        with pytest.raises(StoreError, match="locked by another process"):
            Bank(bank).open("P37", read_only=False, check=False)
        assert "writing" not in Bank(bank).manifest()
    finally:
        holder.kill()
        holder.wait()


def test_unknown_participant_id_is_refused(bank):
    with pytest.raises(BankError, match="must be a participant id"):
        Bank(bank).forget("../etc")


def test_the_graph2d_cache_is_json_and_reloads_the_same_graph(bank, embedder):
    import networkx as nx

    from memora_graph.baselines.graph2d import Graph2DMemory

    built = Graph2DMemory.load(bank, "P09")
    files = sorted(p.name for p in (bank / ".cache").glob("graph2d-P09-*"))
    assert [f.rsplit(".", 1)[1] for f in files] == ["json", "npy"]
    cached = Graph2DMemory.load(bank, "P09")  # from the cache
    assert cached.nodes == built.nodes and (cached.vectors == built.vectors).all()
    assert nx.utils.graphs_equal(cached.graph, built.graph)
    assert cached.search("wash the pan") == built.search("wash the pan")


def test_accept_records_a_bank_built_before_integrity_records(bank):
    from support.corrupt import not_recorded

    not_recorded(bank)
    assert memora("query", bank, "MATCH (v:Video) RETURN count(*) AS n", "--participant", "P09").returncode == 1
    r = memora("verify", bank, "--accept", "P09", "--json")
    assert r.returncode == 0, r.stdout + r.stderr
    assert Bank(bank).manifest()["participants"]["P09"]["integrity"]["tables"]["Video"] == 4
    assert memora("query", bank, "MATCH (v:Video) RETURN count(*) AS n", "--participant", "P09").returncode == 0


def _write_then_die(db, cypher: str) -> None:
    """A writer that commits and dies before any checkpoint: the commit is only in the WAL."""
    import subprocess
    import sys

    code = ("import os, sys, kuzu; db = kuzu.Database(sys.argv[1], auto_checkpoint=False); "
            "kuzu.Connection(db).execute(sys.argv[2]); os._exit(0)")
    subprocess.run([sys.executable, "-c", code, str(db), cypher], check=True)


def _mark(bank, op: str) -> None:
    data = json.loads((bank / "manifest.json").read_text())
    data["writing"] = {"P09": {"op": op, "pid": 2 ** 22 + 7, "since": "2025-01-01T00:00:00+00:00"}}
    (bank / "manifest.json").write_text(json.dumps(data))


def test_an_unfinished_write_is_refused_until_accepted(bank):
    _write_then_die(bank / "P09.kuzu", "CREATE (:Participant {id: 'X99', participant: 'P09'})")
    _mark(bank, "write")
    q = ["query", bank, "MATCH (p:Participant) RETURN p.id AS id ORDER BY id", "--participant", "P09", "--json"]
    r = memora(*q)
    assert r.returncode == 1 and "did not finish" in r.stdout + r.stderr and "--accept P09" in r.stdout + r.stderr
    a = memora("verify", bank, "--accept", "P09")
    assert a.returncode == 0, a.stdout + a.stderr
    assert not (bank / "P09.kuzu.wal").exists()
    r = memora(*q)
    assert r.returncode == 0 and [x["id"] for x in json.loads(r.stdout)] == ["P09", "X99"]  # the committed write kept


def test_a_build_refuses_to_replay_a_log_that_crashes_kuzu(bank):
    from support.corrupt import foreign_wal

    foreign_wal(bank)
    _mark(bank, "build")  # an interrupted build: a log there could be its own, so it is tried in a child
    with pytest.raises(BankError, match=r"P09\.kuzu: Kùzu crashed \(signal \d+\) opening it with P09\.kuzu\.wal"):
        build_bank(bank, ["P09"])
    assert (bank / "P09.kuzu.wal").exists()  # reported, not replayed or removed

import csv
import io
import json

from click.testing import CliRunner

from memora_graph.cli import main


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_query_formats(small_bank):
    path, _ = small_bank
    q = "MATCH (p:Place) WHERE p.participant = $participant RETURN p.location_id AS place, p.turn_count AS turns ORDER BY place"
    js = invoke("query", path, q, "-p", "participant", "P09", "--json")
    assert js.exit_code == 0, js.output
    rows = json.loads(js.output)
    assert rows and set(rows[0]) == {"place", "turns"}
    csv_out = invoke("query", path, q, "-p", "participant", "P09", "--csv")
    parsed = list(csv.DictReader(io.StringIO(csv_out.output)))
    assert [r["place"] for r in parsed] == [r["place"] for r in rows]
    nl = invoke("query", path, q, "-p", "participant", "P09", "--nl")
    assert [json.loads(line) for line in nl.output.strip().splitlines()] == rows
    table = invoke("query", path, q, "-p", "participant", "P09")
    assert "place" in table.output and rows[0]["place"] in table.output


def test_query_is_read_only_unless_write(small_bank, tmp_path):
    import shutil

    path, _ = small_bank
    copy = tmp_path / "b"
    shutil.copytree(path, copy)
    create = "CREATE (:Participant {id: 'X99', participant: 'X99'})"
    r = invoke("query", copy, create, "--participant", "P09")
    assert r.exit_code == 1 and "read-only" in r.output
    r = invoke("query", copy, create, "--participant", "P09", "--write")
    assert r.exit_code == 0, r.output
    r = invoke("query", copy, "MATCH (p:Participant) RETURN p.id AS id ORDER BY id", "--participant", "P09", "--json")
    assert [x["id"] for x in json.loads(r.output)] == ["P09", "X99"]


def test_syntax_error_is_clear(small_bank):
    path, _ = small_bank
    r = invoke("query", path, "MATCH (x) RETRUN x", "--participant", "P09")
    assert r.exit_code == 1 and "Cypher syntax error" in r.output and "Traceback" not in r.output


def test_queries_run_and_stats(small_bank):
    path, _ = small_bank
    r = invoke("queries", "--json")
    names = {q["name"] for q in json.loads(r.output)}
    assert {"object_history", "places_most_used", "location_changes"} <= names
    assert not any(n.startswith("_") for n in names)
    moves = []
    for v in json.loads(invoke("run", path, "videos", "-p", "participant", "P37", "--json").output):
        r = invoke("run", path, "location_changes", "-p", "participant", "P37", "-p", "object", "knife",
                   "-p", "video", v["video"], "--json")
        assert r.exit_code == 0, r.output
        assert {x["video"] for x in json.loads(r.output)} <= {v["video"]}  # a video at a time
        moves += json.loads(r.output)
    assert moves and all(x["moved_from"] != x["moved_to"] for x in moves)
    r = invoke("run", path, "store_counts", "--json")
    assert {x["participant"] for x in json.loads(r.output)} == {"P09", "P37"}
    r = invoke("stats", path, "--json")
    stats = json.loads(r.output)
    assert {s["participant"] for s in stats} == {"P09", "P37"}
    for s in stats:
        assert s["compression"] == round(s["state_events"] / s["entities"], 1)
        assert abs(s["NOOP%"] + s["UPDATE%"] + s["ADD%"] + s["DELETE%"] - 100) < 0.5
    r = invoke("run", path, "nope")
    assert r.exit_code == 1 and "known queries" in r.output


def test_help_has_examples():
    for cmd in ("build", "query", "queries", "run", "stats"):
        r = invoke(cmd, "--help")
        assert r.exit_code == 0 and "Example" in r.output, cmd


def test_csv_flattens_list_columns(small_bank):
    path, _ = small_bank
    q = "MATCH (p:Place) WHERE p.participant = $participant RETURN p.location_id AS place, p.zones AS zones ORDER BY place"
    r = invoke("query", path, q, "-p", "participant", "P37", "--csv")
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(io.StringIO(r.output)))
    js = json.loads(invoke("query", path, q, "-p", "participant", "P37", "--json").output)
    assert [row["zones"] for row in rows] == ["; ".join(x["zones"]) for x in js]


def test_a_one_participant_raw_build_reads_right_and_stderr_has_no_model_loading_bars(tmp_path):
    """What a newcomer saw: '1 participants', 'inferred knowledge: none (MEMORA-Episodic)' on a raw
    build, and transformers' 'Loading weights' progress bar on stderr. A real process, so stderr is real."""
    from support.corrupt import memora

    r = memora("build", tmp_path / "raw", "--mode", "raw", "--participants", "P09", "--quiet", timeout=600)
    assert r.returncode == 0, r.stderr
    assert "1 participant," in r.stdout and "1 participants" not in r.stdout
    assert "tool stores (what one-shot tools map instead of querying Kùzu): 1 participant in" in r.stdout
    assert "inferred knowledge: none (a raw build keeps one record per observation)" in r.stdout
    assert "MEMORA-Episodic" not in r.stdout
    assert "Loading weights" not in r.stderr and "it/s]" not in r.stderr, r.stderr


def test_json_help_says_what_json_prints():
    """`ask` and `tool` print one object with --json; the row commands an array (their --help said so for all)."""
    for cmd in ("ask", "tool"):
        out = " ".join(invoke(cmd, "--help").output.split())
        assert "--json One JSON object" in out and "JSON array" not in out, cmd
    for cmd in ("stats", "query", "verify"):
        assert "A JSON array of objects, one per row." in " ".join(invoke(cmd, "--help").output.split()), cmd

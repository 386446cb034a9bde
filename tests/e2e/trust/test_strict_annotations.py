"""Strict annotations: every bad row is refused with its file, row (line) and column, all of a
file's problems are counted, and no input makes a build grow past the video's known length."""

from __future__ import annotations

import string

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from memora_graph.cli import main
from memora_graph.errors import BankError, DataError
from memora_graph.paths import epic_dir
from memora_graph.perceive.annotations import MAX_PROBLEMS, REQUIRED_COLUMNS, load_annotations, load_video_info
from memora_graph.pipeline import build_bank

HEADER = ",".join(REQUIRED_COLUMNS)
# P01_102 lasts 274.92 s at 50 fps (video_info.csv)
GOOD = "P01_102_0,P01,P01_102,00:00:01.100,00:00:00.54,00:00:02.23,27,111,take knife and plate,take,0,knife,4," \
       "\"['knife', 'plate']\",\"[4, 2]\""
NO_TIMES = "P01_102_5,P01,P01_102,,,,500,600,,,0,,4,,"


def row(**changes) -> str:
    """GOOD with some columns replaced (by name)."""
    import csv
    import io

    values = next(csv.reader(io.StringIO(GOOD)))
    for k, v in changes.items():
        values[REQUIRED_COLUMNS.index(k)] = v
    out = io.StringIO()
    csv.writer(out, lineterminator="").writerow(values)
    return out.getvalue()


def meta(tmp_path, **replace):
    for name in ("video_info.csv", "verb_classes.csv", "noun_classes.csv"):
        (tmp_path / name).write_text(replace.get(name) or (epic_dir() / name).read_text())


def write_csv(tmp_path, *rows, **replace):
    meta(tmp_path, **replace)
    path = tmp_path / "ann.csv"
    path.write_text("\n".join([HEADER, *rows]) + "\n")
    return path


BAD_ROWS = [
    ("same narration_id", [GOOD, row(start_frame="30", stop_frame="120")], "narration_id", "the same narration_id"),
    ("identical row", [GOOD, GOOD], "narration_id", "the same action"),
    ("identical but the id", [GOOD, row(narration_id="P01_102_1")], "narration_id", "the same action"),
    ("start after stop", [row(start_timestamp="00:00:09.00", stop_timestamp="00:00:02.00")], "stop_timestamp",
     "ends before start_timestamp"),
    ("minutes 99", [row(start_timestamp="00:99:99.00")], "start_timestamp", "below 60"),
    ("seconds 61", [row(stop_timestamp="00:00:61.00")], "stop_timestamp", "below 60"),
    ("10 h in a 275 s video", [row(stop_timestamp="10:00:00.00")], "stop_timestamp", "after the end of P01_102"),
    ("99999 hours", [row(start_timestamp="99999:00:00", stop_timestamp="99999:00:01")], "start_timestamp",
     "after the end"),
    ("10^30 frames", [row(narration_id="P01_102_7", start_timestamp="", stop_timestamp="", stop_frame="1" + "0" * 30)],
     "stop_frame", "not an integer"),
    ("a frame past the end", [row(stop_frame="999999")], "stop_frame", "after the end of P01_102"),
    ("no times, frames past the end", [row(start_timestamp="", stop_timestamp="", start_frame="900000",
                                           stop_frame="900100")], "start_frame", "after the end"),
    ("negative frame", [row(start_frame="-5")], "start_frame", "negative"),
    ("stop frame before start", [row(start_frame="200", stop_frame="100")], "stop_frame", "ends before start_frame"),
    ("unknown noun class", [row(noun_class="999")], "noun_class", "unknown noun class"),
    ("unknown verb class", [row(verb_class="97")], "verb_class", "unknown verb class"),
    ("unknown class in the list", [row(all_noun_classes="[4, 999]")], "all_noun_classes", "unknown noun class 999"),
    ("video not in video_info", [row(narration_id="P01_199_0", video_id="P01_199")], "video_id", "not in video_info"),
    ("video of another participant", [row(video_id="P02_102")], "video_id", "does not belong"),
    ("malformed video id", [row(video_id="P01-102")], "video_id", "expected an id"),
    ("empty narration_id", [row(narration_id="")], "narration_id", "empty"),
    ("class as a float", [row(verb_class="1e3")], "verb_class", "not an integer"),
    ("empty class", [row(noun_class="")], "noun_class", "not an integer"),
    ("malformed narration time", [row(narration_timestamp="yesterday")], "narration_timestamp", "HH:MM:SS"),
    ("deeply nested list", [row(all_nouns="[" * 5000 + "]" * 5000)], "all_nouns", "list literal"),
    ("a list of lists", [row(all_noun_classes="[[4], [2]]")], "all_noun_classes", "list literal"),
    ("true as a class", [row(all_noun_classes="[True, 2]")], "all_noun_classes", "list literal"),
    ("fewer classes than nouns", [row(all_noun_classes="[4]")], "all_noun_classes", "1 classes for 2 nouns"),
]


@pytest.mark.parametrize("case,rows,column,says", BAD_ROWS, ids=[c[0] for c in BAD_ROWS])
def test_bad_rows_name_file_row_and_column(tmp_path, case, rows, column, says):
    path = write_csv(tmp_path, *rows)
    with pytest.raises(DataError) as exc:
        load_annotations(path)
    msg = str(exc.value)
    line = len(rows) + 1  # the last row is the bad one; line 1 is the header
    assert str(path) in msg and f"row {line}" in msg and f"column '{column}'" in msg and says in msg, msg


def test_every_problem_is_counted_and_the_first_ones_listed(tmp_path):
    rows = [row(narration_id=f"P01_102_{i}", start_frame=str(i), noun_class="999") for i in range(30)]
    rows.append(row(narration_id="P01_102_99", start_frame="1", stop_timestamp="00:99:00.00"))
    with pytest.raises(DataError) as exc:
        load_annotations(write_csv(tmp_path, *rows))
    msg = str(exc.value)
    assert "31 problems" in msg and f"the first {MAX_PROBLEMS}:" in msg and "... and 11 more" in msg
    assert msg.count("unknown noun class") == MAX_PROBLEMS and "row 2, column 'noun_class'" in msg


@pytest.mark.parametrize("info,column,says", [
    ("video_id,duration,fps\nP01_102,inf,50.0\n", "duration", "not a number"),
    ("video_id,duration,fps\nP01_102,-3,50.0\n", "duration", "above 0"),
    ("video_id,duration,fps\nP01_102,1e12,50.0\n", "duration", "at most 86400"),
    ("video_id,duration,fps\nP01_102,274.92,0\n", "fps", "above 0"),
    ("video_id,duration,fps\nP01_102,274.92,50\nP01_102,274.92,50\n", "video_id", "listed twice"),
])
def test_bad_video_info_is_refused(tmp_path, info, column, says):
    meta(tmp_path, **{"video_info.csv": info})
    with pytest.raises(DataError, match=f"column '{column}': .*{says}"):
        load_video_info(tmp_path)


def test_duplicate_class_ids_are_refused(tmp_path):
    verbs = (epic_dir() / "verb_classes.csv").read_text().splitlines()
    path = write_csv(tmp_path, GOOD, **{"verb_classes.csv": "\n".join(verbs + [verbs[1]]) + "\n"})
    with pytest.raises(DataError, match="verb_classes.csv: row 99 .*column 'id': the same id as row 2"):
        load_annotations(path)


def test_rows_without_times_take_them_from_the_frames(tmp_path):
    df = load_annotations(write_csv(tmp_path, GOOD, NO_TIMES))
    r = df.filter(df["narration_id"] == "P01_102_5").row(0, named=True)
    assert (r["start_s"], r["stop_s"]) == (10.0, 12.0) and r["text_source"] == "class_keys"


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_build_refuses_a_bad_csv_before_touching_the_bank(tmp_path):
    path = write_csv(tmp_path, GOOD, row(narration_id="P01_102_1", start_timestamp="00:99:99.00"))
    bank = tmp_path / "bank"
    r = invoke("build", bank, "--annotations", path, "--quiet")
    assert r.exit_code == 1 and f"{path}: row 3" in r.output and "column 'start_timestamp'" in r.output
    assert "Traceback" not in r.output and not bank.exists()


@pytest.mark.parametrize("args,says", [
    (("--participants", ""), "no participant given"),
    (("--participants", " , "), "no participant given"),
    (("--participants", "P01,../x"), "'../x' is not a participant id"),
])
def test_build_refuses_empty_or_bad_participant_lists(tmp_path, args, says):
    # A bad option value is a usage error (click's exit code 2), named with the option.
    r = invoke("build", tmp_path / "bank", *args, "--quiet")
    assert r.exit_code == 2 and "'--participants'" in r.output and says in r.output
    assert "Traceback" not in r.output and not (tmp_path / "bank").exists()


@pytest.mark.parametrize("bank,says", [
    ("", "the bank path is empty"),
    ("   ", "the bank path is empty"),
    ("{file}", "is not a directory"),
    ("{file}/bank", "is a file, not a directory"),
    ("/proc/memora-bank", "cannot write here"),
])
def test_build_refuses_a_bank_path_it_cannot_write_before_loading_a_model(tmp_path, bank, says):
    (tmp_path / "afile").write_text("x")
    path = bank.replace("{file}", str(tmp_path / "afile"))
    r = invoke("build", path, "--participants", "P09", "--quiet")
    # click itself refuses a file where a directory belongs (usage error, exit 2)
    assert (r.exit_code == 1 and says in r.output or r.exit_code == 2 and "is a file" in r.output), r.output
    assert r.output.startswith("Error: ") or "\nError: " in r.output
    assert r.exception is None or isinstance(r.exception, SystemExit)
    with pytest.raises(BankError, match=says):  # first thing the library call does
        build_bank(path, ["P09"], annotations=str(tmp_path / "no-such.csv"))


# -- property: any row loads or is refused with a DataError ----------------------------------------

_CELL = {
    "narration_id": st.sampled_from(["P01_102_1", "", "P01_102_0", "x"]),
    "participant_id": st.sampled_from(["P01", "", "P02", "P1"]),
    "video_id": st.sampled_from(["P01_102", "P01_199", "P02_102", "", "P01_1020", "P01_102\n"]),
    "timestamp": st.one_of(
        st.sampled_from(["", "00:00:01.00", "00:99:99.00", "10:00:00.00", "99999:00:00", "0:0:0", "-1:00:00.00"]),
        st.builds(lambda h, m, s: f"{h:02d}:{m:02d}:{s:05.2f}", st.integers(0, 120), st.integers(0, 99),
                  st.floats(0, 99.99))),
    "frame": st.one_of(st.integers(-10, 10**31).map(str), st.sampled_from(["", "1.5", "1e30", "x", " 12 ", "１２"])),
    "class": st.one_of(st.integers(-2, 400).map(str), st.sampled_from(["", "1e3", "True", "0x1"])),
    "text": st.text(alphabet=string.printable, max_size=20),
    "list": st.one_of(st.sampled_from(["", "[]", "['knife']", "[4]", "[4, 2]", "[[4]]", "[" * 3000, "['a', 'b']",
                                       "[None]", "[1e999]", "{'a': 1}", "__import__('os')"]),
                      st.text(alphabet=string.printable, max_size=15)),
}
_KIND = {"narration_id": "narration_id", "participant_id": "participant_id", "video_id": "video_id",
         "narration_timestamp": "timestamp", "start_timestamp": "timestamp", "stop_timestamp": "timestamp",
         "start_frame": "frame", "stop_frame": "frame", "narration": "text", "verb": "text", "verb_class": "class",
         "noun": "text", "noun_class": "class", "all_nouns": "list", "all_noun_classes": "list"}


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                  HealthCheck.too_slow])
@given(st.lists(st.fixed_dictionaries({c: _CELL[_KIND[c]] for c in REQUIRED_COLUMNS}), min_size=1, max_size=3))
def test_no_generated_row_makes_the_loader_traceback(tmp_path, rows):
    import csv

    meta(tmp_path)
    path = tmp_path / "gen.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=REQUIRED_COLUMNS)
        w.writeheader()
        w.writerows(rows)
    try:
        df = load_annotations(path)
    except DataError as exc:
        assert str(path) in str(exc)
        return
    assert (df["stop_s"] >= df["start_s"]).all() and (df["stop_s"] <= 274.92 + 1.0).all()

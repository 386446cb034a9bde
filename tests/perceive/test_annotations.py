import polars as pl
import pytest

from memora_graph.errors import DataError
from memora_graph.paths import epic_dir
from memora_graph.perceive.annotations import REQUIRED_COLUMNS, load_annotations

HEADER = ",".join(REQUIRED_COLUMNS)
GOOD = 'P01_102_0,P01,P01_102,00:00:01.100,00:00:00.54,00:00:02.23,27,111,take knife and plate,take,0,knife,4,"[\'knife\', \'plate\']","[4, 2]"'


def _csv(tmp_path, *rows, header=HEADER):
    for name in ("video_info.csv", "verb_classes.csv", "noun_classes.csv"):
        (tmp_path / name).write_text((epic_dir() / name).read_text())
    path = tmp_path / "ann.csv"
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


def test_bundled_annotations_load_and_fill_gaps():
    df = load_annotations()
    assert df.height == 37455
    assert df["participant_id"].n_unique() == 18
    # 22.5% of rows had no narration: their text is built from the class keys
    built = df.filter(pl.col("text_source") == "class_keys")
    assert built.height == 8431
    assert built["narration"].str.len_chars().min() > 0
    # rows of P35/P37 without timestamps get times from frames / 50 fps
    assert df["start_s"].null_count() == 0
    assert (df["stop_s"] >= df["start_s"]).all()


def test_missing_timestamp_derived_from_frames(tmp_path):
    row = "P01_102_9,P01,P01_102,,,,500,600,,,0,,4,,"
    df = load_annotations(_csv(tmp_path, row))
    r = df.row(0, named=True)
    assert r["start_s"] == pytest.approx(10.0) and r["stop_s"] == pytest.approx(12.0)
    assert r["narration"] == "take knife" and r["all_nouns"] == ["knife"]


@pytest.mark.parametrize("row,column", [
    (GOOD.replace(",27,111,", ",x27,111,"), "start_frame"),
    (GOOD.replace("00:00:00.54", "0:0:bad"), "start_timestamp"),
    (GOOD.replace(",take,0,", ",take,999,"), "verb_class"),
    (GOOD.replace('"[4, 2]"', '"[4]"'), "all_noun_classes"),
    (GOOD.replace('"[\'knife\', \'plate\']"', '"knife, plate"'), "all_nouns"),
    (GOOD.replace("P01,P01_102", "P01,P02_102", 1), "video_id"),
])
def test_malformed_row_names_file_row_and_column(tmp_path, row, column):
    path = _csv(tmp_path, GOOD, row)
    with pytest.raises(DataError) as exc:
        load_annotations(path)
    msg = str(exc.value)
    assert str(path) in msg and "row 3" in msg and f"column '{column}'" in msg


def test_missing_column_is_named(tmp_path):
    path = _csv(tmp_path, GOOD.removesuffix(',"[4, 2]"'), header=HEADER.rsplit(",", 1)[0])
    with pytest.raises(DataError, match="all_noun_classes"):
        load_annotations(path)

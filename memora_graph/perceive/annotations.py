"""Load EPIC-KITCHENS-100 action annotations into one validated polars frame.

This is the input of the CPU perception path: narrated actions instead of pixels. The loader
fills the two known gaps of the bundled subset (rows without narration text; rows without
timestamps) and refuses a malformed file with an error that names the file, row and column.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from memora_graph.errors import DataError
from memora_graph.paths import default_annotations

REQUIRED_COLUMNS = [
    "narration_id", "participant_id", "video_id", "narration_timestamp", "start_timestamp",
    "stop_timestamp", "start_frame", "stop_frame", "narration", "verb", "verb_class", "noun",
    "noun_class", "all_nouns", "all_noun_classes",
]
_TS = re.compile(r"^(\d+):(\d{2}):(\d{2}(?:\.\d+)?)$")
_VIDEO = re.compile(r"^P\d{2}_\d{2,3}$")


@dataclass(frozen=True)
class ClassTables:
    verbs: dict[int, str]
    nouns: dict[int, str]
    noun_category: dict[int, str]


def _fail(path: Path, line: int, column: str, value: object, why: str) -> DataError:
    return DataError(f"{path}: row {line} (line {line} of the file), column '{column}': {why} (got {value!r})")


def _read_strings(path: Path) -> pl.DataFrame:
    if not path.exists():
        raise DataError(f"{path}: file not found")
    try:
        return pl.read_csv(path, infer_schema=False).with_columns(pl.all().fill_null(""))
    except pl.exceptions.PolarsError as exc:
        raise DataError(f"{path}: not a readable CSV file: {exc}") from exc


def load_class_tables(folder: Path) -> ClassTables:
    out = {}
    for kind in ("verb", "noun"):
        path = folder / f"{kind}_classes.csv"
        df = _read_strings(path)
        for col in ("id", "key"):
            if col not in df.columns:
                raise DataError(f"{path}: missing column '{col}'")
        ids = df["id"].cast(pl.Int64, strict=False)
        bad = ids.is_null().arg_true()
        if len(bad):
            i = int(bad[0])
            raise _fail(path, i + 2, "id", df["id"][i], "not an integer")
        out[kind] = dict(zip(ids.to_list(), df["key"].to_list()))
        if kind == "noun":
            cats = df["category"].to_list() if "category" in df.columns else [""] * len(df)
            out["cat"] = dict(zip(ids.to_list(), cats))
    return ClassTables(verbs=out["verb"], nouns=out["noun"], noun_category=out["cat"])


def load_video_info(folder: Path) -> pl.DataFrame:
    path = folder / "video_info.csv"
    df = _read_strings(path)
    for col in ("video_id", "duration", "fps"):
        if col not in df.columns:
            raise DataError(f"{path}: missing column '{col}'")
    out = df.select(
        "video_id",
        pl.col("duration").cast(pl.Float64, strict=False),
        pl.col("fps").cast(pl.Float64, strict=False),
    )
    for col in ("duration", "fps"):
        bad = out[col].is_null().arg_true()
        if len(bad):
            i = int(bad[0])
            raise _fail(path, i + 2, col, df[col][i], "not a number")
    return out


def _seconds(ts: str) -> float | None:
    m = _TS.match(ts)
    if not m:
        return None
    return int(m.group(1)) * 3600 + int(m.group(2)) * 60 + float(m.group(3))


def _parse_list(text: str, kind: type) -> list | None:
    if text == "":
        return []
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return None
    if not isinstance(value, list) or not all(isinstance(v, kind) for v in value):
        return None
    return value


def noun_phrase(noun: str) -> str:
    """EPIC writes 'container:plastic' for 'plastic container'; read it as English."""
    parts = [p for p in noun.replace("_", " ").split(":") if p]
    return " ".join(reversed(parts)) if parts else noun


def load_annotations(
    path: str | Path | None = None,
    participants: list[str] | None = None,
    meta_dir: str | Path | None = None,
) -> pl.DataFrame:
    """Return one row per action, sorted by video and start time.

    Columns: narration_id, participant_id, video_id, start_s, stop_s, narration, verb,
    verb_class, noun, noun_class, all_nouns (list[str]), all_noun_classes (list[int]),
    text_source ('annotation' or 'class_keys'), row (1-based line in the file).
    `meta_dir` holds video_info.csv and the class tables (default: beside the CSV).
    """
    path = Path(path) if path else default_annotations()
    meta = Path(meta_dir) if meta_dir else path.parent
    raw = _read_strings(path)
    missing = [c for c in REQUIRED_COLUMNS if c not in raw.columns]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(missing)}; expected the 15 columns of EPIC_100_train.csv")
    raw = raw.with_row_index("row", offset=2)  # line 1 is the header
    if participants:
        raw = raw.filter(pl.col("participant_id").is_in(participants))
    classes = load_class_tables(meta)
    fps = dict(load_video_info(meta).select("video_id", "fps").iter_rows())

    records: list[dict] = []
    for r in raw.iter_rows(named=True):
        line = r["row"]
        for col in ("narration_id", "participant_id", "video_id"):
            if not r[col]:
                raise _fail(path, line, col, r[col], "empty")
        if not _VIDEO.match(r["video_id"]):
            raise _fail(path, line, "video_id", r["video_id"], "expected an id like P01_102")
        if not r["video_id"].startswith(r["participant_id"] + "_"):
            raise _fail(path, line, "video_id", r["video_id"], f"does not belong to participant {r['participant_id']}")
        ints = {}
        for col in ("start_frame", "stop_frame", "verb_class", "noun_class"):
            try:
                ints[col] = int(r[col])
            except ValueError:
                raise _fail(path, line, col, r[col], "not an integer") from None
        if ints["verb_class"] not in classes.verbs:
            raise _fail(path, line, "verb_class", r["verb_class"], "unknown verb class")
        if ints["noun_class"] not in classes.nouns:
            raise _fail(path, line, "noun_class", r["noun_class"], "unknown noun class")
        if ints["stop_frame"] < ints["start_frame"]:
            raise _fail(path, line, "stop_frame", r["stop_frame"], "ends before start_frame")
        times = {}
        for col in ("start_timestamp", "stop_timestamp"):
            if r[col]:
                times[col] = _seconds(r[col])
                if times[col] is None:
                    raise _fail(path, line, col, r[col], "expected HH:MM:SS.ss")
        if len(times) < 2:
            rate = fps.get(r["video_id"])
            if rate is None:
                raise _fail(path, line, "video_id", r["video_id"], "no timestamps and no fps in video_info.csv")
            times = {"start_timestamp": ints["start_frame"] / rate, "stop_timestamp": ints["stop_frame"] / rate}
        nouns = _parse_list(r["all_nouns"], str)
        if nouns is None:
            raise _fail(path, line, "all_nouns", r["all_nouns"], "expected a list literal such as ['knife', 'plate']")
        noun_classes = _parse_list(r["all_noun_classes"], int)
        if noun_classes is None:
            raise _fail(path, line, "all_noun_classes", r["all_noun_classes"], "expected a list literal such as [4, 2]")
        if len(nouns) != len(noun_classes):
            raise _fail(path, line, "all_noun_classes", r["all_noun_classes"], f"{len(noun_classes)} classes for {len(nouns)} nouns")
        verb_key = classes.verbs[ints["verb_class"]]
        noun_key = classes.nouns[ints["noun_class"]]
        verb = r["verb"] or verb_key
        noun = r["noun"] or noun_key
        if not nouns:
            nouns, noun_classes = [noun], [ints["noun_class"]]
        narration = r["narration"]
        source = "annotation"
        if not narration:
            narration = f"{verb_key.replace('-', ' ')} {noun_phrase(noun_key)}"
            source = "class_keys"
        records.append({
            "narration_id": r["narration_id"], "participant_id": r["participant_id"],
            "video_id": r["video_id"], "start_s": float(times["start_timestamp"]),
            "stop_s": float(times["stop_timestamp"]), "narration": narration, "verb": verb,
            "verb_class": ints["verb_class"], "verb_key": verb_key, "noun": noun,
            "noun_class": ints["noun_class"], "all_nouns": nouns,
            "all_noun_classes": noun_classes, "text_source": source, "row": line,
        })
    schema = {
        "narration_id": pl.String, "participant_id": pl.String, "video_id": pl.String,
        "start_s": pl.Float64, "stop_s": pl.Float64, "narration": pl.String, "verb": pl.String,
        "verb_class": pl.Int64, "verb_key": pl.String, "noun": pl.String, "noun_class": pl.Int64,
        "all_nouns": pl.List(pl.String), "all_noun_classes": pl.List(pl.Int64),
        "text_source": pl.String, "row": pl.Int64,
    }
    df = pl.DataFrame(records, schema=schema, orient="row") if records else pl.DataFrame(schema=schema)
    return df.sort(["video_id", "start_s", "stop_s", "narration_id"])

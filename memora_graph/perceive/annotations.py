"""Load EPIC-KITCHENS-100 action annotations into one validated polars frame.

This is the input of the CPU perception path: narrated actions instead of pixels. The loader
fills the two known gaps of the bundled subset (rows without narration text; rows without
timestamps) and refuses a malformed file with an error that names the file, row and column.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import math
import operator
import re
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from memora_graph.errors import DataError
from memora_graph.paths import default_annotations
from memora_graph.perceive.bounds import MAX_VIDEO_SECONDS

REQUIRED_COLUMNS = [
    "narration_id", "participant_id", "video_id", "narration_timestamp", "start_timestamp",
    "stop_timestamp", "start_frame", "stop_frame", "narration", "verb", "verb_class", "noun",
    "noun_class", "all_nouns", "all_noun_classes",
]
_TS = re.compile(r"^(\d{1,6}):(\d{2}):(\d{2}(?:\.\d+)?)$")
_VIDEO = re.compile(r"^P\d{2}_\d{2,3}$")
MAX_PROBLEMS = 20  # problems listed in one error (all are counted)
MAX_FPS = 1000.0
TOLERANCE_SECONDS = 1.0  # an action may end this much after the video's recorded duration (rounding)


@dataclass(frozen=True)
class ClassTables:
    verbs: dict[int, str]
    nouns: dict[int, str]
    noun_category: dict[int, str]


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _fail(path: Path, line: int, column: str, value: object, why: str) -> DataError:
    return DataError(f"{path}: row {line} (line {line} of the file), column '{column}': {why} (got {_shown(value)})")


class _Problems:
    """Every problem of a file, so that one run names them all (the first MAX_PROBLEMS) rather
    than one per attempt."""

    def __init__(self, path: Path):
        self.path = path
        self.items: list[tuple[int, str, object, str]] = []

    def add(self, line: int, column: str, value: object, why: str) -> None:
        self.items.append((line, column, value, why))

    def check(self) -> None:
        if not self.items:
            return
        if len(self.items) == 1:
            raise _fail(self.path, *self.items[0])
        shown = self.items[:MAX_PROBLEMS]
        lines = [f"  row {line}, column '{col}': {why} (got {_shown(value)})" for line, col, value, why in shown]
        more = f"\n  ... and {len(self.items) - len(shown)} more" if len(self.items) > len(shown) else ""
        raise DataError(f"{self.path}: {len(self.items)} problems (a row is its line in the file), the first "
                        f"{len(shown)}:\n" + "\n".join(lines) + more)


def _read_strings(path: Path) -> pl.DataFrame:
    if not path.exists():
        raise DataError(f"{path}: file not found")
    if not path.is_file():
        raise DataError(f"{path}: not a file")
    try:
        return pl.read_csv(path, infer_schema=False).with_columns(pl.all().fill_null(""))
    except pl.exceptions.PolarsError as exc:
        raise DataError(f"{path}: not a readable CSV file: {exc}") from exc
    except (OSError, UnicodeError) as exc:
        raise DataError(f"{path}: cannot be read ({exc})") from exc


def load_class_tables(folder: Path) -> ClassTables:
    out = {}
    for kind in ("verb", "noun"):
        path = folder / f"{kind}_classes.csv"
        df = _read_strings(path)
        for col in ("id", "key"):
            if col not in df.columns:
                raise DataError(f"{path}: missing column '{col}'")
        problems = _Problems(path)
        seen: dict[int, int] = {}
        for i, (raw, key) in enumerate(zip(df["id"].to_list(), df["key"].to_list())):
            value = _int(raw)
            if value is None:
                problems.add(i + 2, "id", raw, "not an integer")
            elif value in seen:
                problems.add(i + 2, "id", raw, f"the same id as row {seen[value]}")
            else:
                seen[value] = i + 2
            if not key:
                problems.add(i + 2, "key", key, "empty")
        problems.check()
        ids = [int(v) for v in df["id"].to_list()]
        out[kind] = dict(zip(ids, df["key"].to_list()))
        if kind == "noun":
            cats = df["category"].to_list() if "category" in df.columns else [""] * len(df)
            out["cat"] = dict(zip(ids, cats))
    return ClassTables(verbs=out["verb"], nouns=out["noun"], noun_category=out["cat"])


def load_video_info(folder: Path) -> pl.DataFrame:
    """video_id, duration (s) and fps of every video, each checked: a video's duration bounds the
    times of its actions, and so the work and memory of building it."""
    path = folder / "video_info.csv"
    df = _read_strings(path)
    for col in ("video_id", "duration", "fps"):
        if col not in df.columns:
            raise DataError(f"{path}: missing column '{col}'")
    problems = _Problems(path)
    seen: dict[str, int] = {}
    rows = []
    for i, (video, duration, fps) in enumerate(zip(df["video_id"].to_list(), df["duration"].to_list(),
                                                   df["fps"].to_list())):
        line = i + 2
        if not video:
            problems.add(line, "video_id", video, "empty")
        elif video in seen:
            problems.add(line, "video_id", video, f"listed twice (first on row {seen[video]})")
        else:
            seen[video] = line
        d, f = _float(duration), _float(fps)
        if d is None:
            problems.add(line, "duration", duration, "not a number")
        elif not 0 < d <= MAX_VIDEO_SECONDS:
            problems.add(line, "duration", duration, f"a duration in seconds above 0 and at most {MAX_VIDEO_SECONDS:.0f}")
        if f is None:
            problems.add(line, "fps", fps, "not a number")
        elif not 0 < f <= MAX_FPS:
            problems.add(line, "fps", fps, f"frames per second above 0 and at most {MAX_FPS:.0f}")
        rows.append((video, d, f))
    problems.check()
    return pl.DataFrame(rows, schema={"video_id": pl.String, "duration": pl.Float64, "fps": pl.Float64}, orient="row")


def _int(text: str) -> int | None:
    if len(text) > 19:  # more digits than a frame or a class can have (10^30 frames)
        return None
    try:
        return int(text)
    except ValueError:
        return None


def _float(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _seconds(ts: str) -> float | None:
    """HH:MM:SS(.ss) in seconds; None if malformed or minutes / seconds are 60 or more."""
    m = _TS.match(ts)
    if not m:
        return None
    minutes, seconds = int(m.group(2)), float(m.group(3))
    if minutes >= 60 or seconds >= 60:
        return None
    return int(m.group(1)) * 3600 + minutes * 60 + seconds


def _parse_list(text: str, kind: type) -> list | None:
    parsed = _literal_list(text, kind)
    return None if parsed is None else list(parsed)


@functools.lru_cache(maxsize=8192)  # the same few hundred lists recur across 37k rows
def _literal_list(text: str, kind: type) -> tuple | None:
    if text == "":
        return ()
    if len(text) > 100_000:
        return None
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError, TypeError, RecursionError, MemoryError):
        return None
    if not isinstance(value, list) or not all(type(v) is kind for v in value):
        return None
    return tuple(value)


def noun_phrase(noun: str) -> str:
    """EPIC writes 'container:plastic' for 'plastic container'; read it as English."""
    parts = [p for p in noun.replace("_", " ").split(":") if p]
    return " ".join(reversed(parts)) if parts else noun


_CONTENT = operator.itemgetter(*[c for c in REQUIRED_COLUMNS if c != "narration_id"])  # a row but its id


def _check_row(r: dict, classes: ClassTables, videos: dict, problems: _Problems, first_id: dict,
               first_row: dict) -> dict | None:
    """One annotation row as a record, or None with its problems added. Times and frames must lie
    within the video (video_info.csv), which bounds what a build of it makes."""
    line = r["row"]
    add = functools.partial(problems.add, line)
    before = len(problems.items)
    for col in ("narration_id", "participant_id", "video_id"):
        if not r[col]:
            add(col, r[col], "empty")
    if before != len(problems.items):
        return None
    # a digest of the row but its id, not the row's 14 strings: kept for every row (1.15 M at
    # 1,000 hours, ~1 GB as tuples); 128 bits, so two different rows never share one
    key = hashlib.blake2b(repr(_CONTENT(r)).encode(), digest_size=16).digest()
    if key in first_row:
        add("narration_id", r["narration_id"], f"the same action as row {first_row[key]} (every other column is equal)")
        return None
    first_row[key] = line
    if r["narration_id"] in first_id:  # the row's other problems are its own: keep checking
        add("narration_id", r["narration_id"], f"the same narration_id as row {first_id[r['narration_id']]}")
    else:
        first_id[r["narration_id"]] = line
    before = len(problems.items)
    video = r["video_id"]
    if not _VIDEO.match(video):
        add("video_id", video, "expected an id like P01_102")
        return None
    if not video.startswith(r["participant_id"] + "_"):
        add("video_id", video, f"does not belong to participant {r['participant_id']}")
        return None
    if video not in videos:
        add("video_id", video, "not in video_info.csv (its duration and fps bound the action's times)")
        return None
    duration, fps = videos[video]
    ints = {}
    for col in ("start_frame", "stop_frame", "verb_class", "noun_class"):
        ints[col] = _int(r[col])
        if ints[col] is None:
            add(col, r[col], "not an integer")
        elif ints[col] < 0:
            add(col, r[col], "negative")
    if before != len(problems.items):
        return None
    if ints["verb_class"] not in classes.verbs:
        add("verb_class", r["verb_class"], "unknown verb class (not in verb_classes.csv)")
    if ints["noun_class"] not in classes.nouns:
        add("noun_class", r["noun_class"], "unknown noun class (not in noun_classes.csv)")
    last_frame = (duration + TOLERANCE_SECONDS) * fps
    if ints["stop_frame"] < ints["start_frame"]:
        add("stop_frame", r["stop_frame"], f"ends before start_frame {ints['start_frame']}")
    for col in ("start_frame", "stop_frame"):
        if ints[col] > last_frame:
            add(col, r[col], f"after the end of {video} ({duration:g} s at {fps:g} fps: {duration * fps:.0f} frames)")
    times = {}
    for col in ("narration_timestamp", "start_timestamp", "stop_timestamp"):
        if r[col]:
            times[col] = _seconds(r[col])
            if times[col] is None:
                add(col, r[col], "expected HH:MM:SS.ss, minutes and seconds below 60")
            elif col != "narration_timestamp" and times[col] > duration + TOLERANCE_SECONDS:  # unused; EPIC has
                # narration times past the end (P28_104_206)
                add(col, r[col], f"after the end of {video} ({duration:g} s)")
    if before != len(problems.items):
        return None
    times.pop("narration_timestamp", None)
    if len(times) < 2:  # no timestamps: from the frames, which lie within the video
        times = {"start_timestamp": ints["start_frame"] / fps, "stop_timestamp": ints["stop_frame"] / fps}
    elif times["stop_timestamp"] < times["start_timestamp"]:
        add("stop_timestamp", r["stop_timestamp"], f"ends before start_timestamp {r['start_timestamp']}")
    nouns = _parse_list(r["all_nouns"], str)
    if nouns is None:
        add("all_nouns", r["all_nouns"], "expected a list literal such as ['knife', 'plate']")
    noun_classes = _parse_list(r["all_noun_classes"], int)
    if noun_classes is None:
        add("all_noun_classes", r["all_noun_classes"], "expected a list literal such as [4, 2]")
    elif nouns is not None and len(nouns) != len(noun_classes):
        add("all_noun_classes", r["all_noun_classes"], f"{len(noun_classes)} classes for {len(nouns)} nouns")
    elif any(c not in classes.nouns for c in noun_classes):
        unknown = next(c for c in noun_classes if c not in classes.nouns)
        add("all_noun_classes", r["all_noun_classes"], f"unknown noun class {unknown} (not in noun_classes.csv)")
    if before != len(problems.items):
        return None
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
    return {
        "narration_id": r["narration_id"], "participant_id": r["participant_id"],
        "video_id": video, "start_s": float(times["start_timestamp"]),
        "stop_s": float(times["stop_timestamp"]), "narration": narration, "verb": verb,
        "verb_class": ints["verb_class"], "verb_key": verb_key, "noun": noun,
        "noun_class": ints["noun_class"], "all_nouns": nouns,
        "all_noun_classes": noun_classes, "text_source": source, "row": line,
    }


# the columns of a checked action row, whatever the source (EPIC annotations or free-text narrations)
ACTION_SCHEMA = {
    "narration_id": pl.String, "participant_id": pl.String, "video_id": pl.String,
    "start_s": pl.Float64, "stop_s": pl.Float64, "narration": pl.String, "verb": pl.String,
    "verb_class": pl.Int64, "verb_key": pl.String, "noun": pl.String, "noun_class": pl.Int64,
    "all_nouns": pl.List(pl.String), "all_noun_classes": pl.List(pl.Int64),
    "text_source": pl.String, "row": pl.Int64,
}


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
    if participants is not None:
        raw = raw.filter(pl.col("participant_id").is_in(list(participants)))
    classes = load_class_tables(meta)
    videos = {v: (d, f) for v, d, f in load_video_info(meta).iter_rows()}
    problems = _Problems(path)
    # checked rows become columns a chunk at a time: a dict per row for the whole file at once
    # was ~2 GB at 1,000 hours of video (1.15 M rows), the build's peak before it edited anything
    chunks: list[pl.DataFrame] = []
    records: list[dict] = []
    first_id: dict[str, int] = {}
    first_row: dict[bytes, int] = {}
    for r in raw.iter_rows(named=True):
        record = _check_row(r, classes, videos, problems, first_id, first_row)
        if record is not None:
            records.append(record)
            if len(records) >= _ROWS_PER_CHUNK:
                chunks.append(pl.DataFrame(records, schema=ACTION_SCHEMA, orient="row"))
                records = []
    problems.check()
    if records:
        chunks.append(pl.DataFrame(records, schema=ACTION_SCHEMA, orient="row"))
    df = pl.concat(chunks, rechunk=True) if chunks else pl.DataFrame(schema=ACTION_SCHEMA)
    return df.sort(["video_id", "start_s", "stop_s", "narration_id"])


_ROWS_PER_CHUNK = 50_000

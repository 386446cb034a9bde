"""Free-text narrations -> the action rows perception reads, from any narration source.

A narration table is CSV, JSONL or Parquet with `video_id, start, end, text` and an optional
`participant`: an Ego4D-style log ("#C C takes a knife from the drawer"), a caption log, a
robot's perception stream. Each text is read at the class level with the lexicon the question
reader uses (memora_graph/perceive/lexicon.py): its first action's verb class and object
classes become the row's EPIC verb / noun keys, so a row here and an EPIC annotation row go
through the same perception (`perceive_video`, `perceive_moment`). Words no class covers are
kept: the narration text is stored as written, an unknown object word becomes an object of
its own kind (no class), an unknown verb is kept as the action word, and `Unknown` reports how
many and which, never dropping any silently. `memora remember` reads its text the same way.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

from memora_graph.errors import DataError
from memora_graph.ids import RULE, is_participant_id
from memora_graph.perceive.annotations import ACTION_SCHEMA, ClassTables, load_class_tables
from memora_graph.perceive.bounds import seconds_problem
from memora_graph.perceive.lexicon import Lexicon, lemma

REQUIRED = ("video_id", "start", "end", "text")
FORMATS = {".csv": "csv", ".tsv": "csv", ".jsonl": "jsonl", ".ndjson": "jsonl", ".parquet": "parquet", ".pq": "parquet"}
# Ego4D's markers: "#C" the camera wearer (the memory's person), "#O" someone else, "#unsure", "#summary"
_EGO4D_SUBJECT = re.compile(r"^\s*#\s*C\s+C\b\s*", re.IGNORECASE)
_MARKER = re.compile(r"#\s*(?:unsure|summary|c|o)\b", re.IGNORECASE)
# words a narration uses around its verb and objects that name no action or object
_FUNCTION = frozenset("""the a an of his her their its this that these those some any with from into onto in on
    at to by for off out up down over under inside near beside back away then and or but while using c o
    one two three both each other another there here now again still just very also""".split())
MAX_TEXT = 2000


@dataclass
class Reading:
    """What a narration says, as classes (`verb_key` / `nouns` are EPIC class keys, or the words
    themselves where no class covers them: `verb_class` / a noun class of -1)."""

    text: str
    verb: str
    verb_key: str
    verb_class: int
    nouns: list[str]
    noun_classes: list[int]
    unknown: list[str] = field(default_factory=list)

    @property
    def text_only(self) -> bool:
        """No word a class covers and no object read: the moment is kept as its text alone."""
        return self.verb_class == -1 and not self.nouns


@dataclass
class Unknown:
    """Words of a source no class covers: kept (as text, or as their own object kinds), counted."""

    rows: int = 0  # rows with at least one unknown word
    words: Counter = field(default_factory=Counter)

    def add(self, reading: Reading) -> None:
        if reading.unknown:
            self.rows += 1
            self.words.update(reading.unknown)

    def summary(self, top: int = 20) -> str:
        if not self.words:
            return "every word of the narrations maps to a verb or noun class"
        listed = ", ".join(f"{w} ({n})" for w, n in self.words.most_common(top))
        more = f", +{len(self.words) - top} more" if len(self.words) > top else ""
        return (f"{sum(self.words.values())} unknown words ({len(self.words)} distinct) in {self.rows} narrations, kept "
                f"as text: {listed}{more}")

    def as_dict(self) -> dict:
        return {"rows": self.rows, "total": sum(self.words.values()), "distinct": len(self.words),
                "words": dict(self.words.most_common())}


def inflected_unknown(found: list[tuple[str, str]]) -> list[str]:
    """The unknown words (lemma, as written) inflected as a verb is ("grasps", "welded", "holding")."""
    return [w for w, said in found if re.search(r"(?<!s)s$|ed$|ing$", said)]


class NarrationReader:
    """Reads free-text narrations into classes with the bundled EPIC class tables."""

    def __init__(self, classes: ClassTables | None = None, lexicon: Lexicon | None = None):
        from memora_graph.paths import epic_dir

        self.classes = classes or load_class_tables(epic_dir())
        self.lexicon = lexicon or Lexicon.load()
        self._verb_id = {k: i for i, k in self.classes.verbs.items()}
        self._noun_id = {k: i for i, k in self.classes.nouns.items()}

    def clean(self, text: str) -> str:
        """The narration without Ego4D's markers ("#C C takes a cup" -> "takes a cup")."""
        return re.sub(r"\s+", " ", _MARKER.sub(" ", _EGO4D_SUBJECT.sub("", text))).strip()

    def _unknown_words(self, text: str) -> list[tuple[str, str]]:
        """(lemma, word as written) of each word no class covers, in order, once each."""
        out: dict[str, str] = {}
        for w in re.findall(r"[a-z]+", text.lower()):
            if len(w) <= 2 or w in _FUNCTION or w in self.lexicon.known or lemma(w, self.lexicon.known) in self.lexicon.known:
                continue
            out.setdefault(lemma(w, self.lexicon.known), w)
        return list(out.items())

    def read(self, text: str) -> Reading:
        cleaned = self.clean(text)
        clauses = self.lexicon.parse(cleaned)
        main = next((c for c in clauses if c.verb), clauses[0] if clauses else None)
        found = self._unknown_words(cleaned)
        unknown = [w for w, _ in found]
        if main is not None and main.verb:
            verb_key = main.verb
            verb_class = self._verb_id.get(verb_key, -1)
        else:  # no verb class: the first word inflected as a verb ("grasps", "welded"), else the first
            # word no class covers, is the action word, kept as written ("robot grasps ..." -> grasp)
            verb_key = (inflected_unknown(found) or unknown or ["do"])[0]
            verb_class = -1
        nouns = list(dict.fromkeys(main.nouns if main is not None else []))
        if not nouns:
            nouns = list(dict.fromkeys(n for c in clauses for n in c.nouns))
        classes = [self._noun_id.get(n, -1) for n in nouns]
        if not nouns and (verb_class != -1 or verb_key in inflected_unknown(found)):
            objects = [w for w in unknown if w != verb_key]
            if objects:  # an object no class covers, of a narrated action: its own kind, never dropped
                nouns, classes = [objects[-1]], [-1]
        # no word any class covers and none that reads as a verb ("flibber the zorp quux"): nothing
        # tells an action from an object, so no word becomes an object; the text is kept as written
        return Reading(text=cleaned or text.strip(), verb=verb_key, verb_key=verb_key, verb_class=verb_class,
                       nouns=nouns, noun_classes=classes, unknown=unknown)

    def action(self, reading: Reading, participant: str, video_id: str, start: float, end: float,
               narration_id: str, row: int = 0) -> dict:
        """An action row in the shape of `load_annotations`' rows (what perception reads)."""
        return {
            "narration_id": narration_id, "participant_id": participant, "video_id": video_id,
            "start_s": float(start), "stop_s": float(end), "narration": reading.text, "verb": reading.verb,
            "verb_class": reading.verb_class, "verb_key": reading.verb_key,
            "noun": reading.nouns[0] if reading.nouns else "",
            "noun_class": reading.noun_classes[0] if reading.noun_classes else -1,
            "all_nouns": list(reading.nouns), "all_noun_classes": list(reading.noun_classes),
            "text_source": "narration", "row": row,
        }


def check_moment(where: str, video_id: object, start: object, end: object, text: object,
                 participant: object = None) -> tuple[str, float, float, str]:
    """One narration's fields, checked; a DataError names `where` (file and row, or the call)
    and the field at fault."""
    def fail(fld: str, value: object, why: str) -> DataError:
        shown = repr(value) if len(repr(value)) <= 80 else repr(value)[:77] + "..."
        return DataError(f"{where}, field '{fld}': {why} (got {shown})")

    if participant is not None and not is_participant_id(participant):
        raise fail("participant", participant, f"expected a participant id: {RULE}")
    if not isinstance(video_id, str) or not video_id.strip():
        raise fail("video_id", video_id, "empty; name the video (or episode) the narration belongs to")
    if any(c in video_id for c in "\n\r\t#") or len(video_id) > 200:
        raise fail("video_id", video_id, "must be one line without '#' (at most 200 characters)")
    times = []
    for fld, value in (("start", start), ("end", end)):
        why = seconds_problem(value)  # finite, 0 to 24 h (perceive/bounds.py)
        if why:
            raise fail(fld, value, why)
        times.append(float(value))
    if times[1] < times[0]:
        raise fail("end", end, f"ends before start {times[0]:g}")
    if not isinstance(text, str) or not text.strip():
        raise fail("text", text, "empty; the narration says what happened")
    if len(text) > MAX_TEXT:
        raise fail("text", text, f"longer than {MAX_TEXT} characters")
    return video_id.strip(), times[0], times[1], text


def json_lines(lines, name: str, after_error: str = ""):
    """(row number, parsed value) for each non-blank line of a JSON Lines stream; a line that is not
    JSON raises a DataError naming `name` and the row (`after_error` is appended to its message)."""
    for n, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            yield n, json.loads(line)
        except json.JSONDecodeError as exc:
            raise DataError(f"{name}: row {n}: not JSON ({exc.msg}){after_error}") from None


def _read_table(path: Path) -> pl.DataFrame:
    kind = FORMATS.get(path.suffix.lower())
    if kind is None:
        raise DataError(f"{path}: unknown narration format {path.suffix!r}; use .csv, .jsonl or .parquet "
                        "(columns video_id, start, end, text, optional participant)")
    try:
        if kind == "csv":
            return pl.read_csv(path, infer_schema=False, separator="\t" if path.suffix.lower() == ".tsv" else ",")
        if kind == "parquet":
            return pl.read_parquet(path)
        rows = []
        with path.open(encoding="utf-8") as fh:
            for n, row in json_lines(fh, str(path)):
                if not isinstance(row, dict):
                    raise DataError(f"{path}: row {n}: expected a JSON object with video_id, start, end, text")
                rows.append({k: (v if isinstance(v, str) or v is None else json.dumps(v)) for k, v in row.items()}
                            | {"__row": n})
        return pl.DataFrame(rows, infer_schema_length=None) if rows else pl.DataFrame()
    except DataError:
        raise
    except (OSError, UnicodeDecodeError, pl.exceptions.PolarsError) as exc:
        raise DataError(f"{path}: cannot be read as {kind} ({exc})") from exc


def load_narrations(path: str | Path, participant: str | None = None, reader: NarrationReader | None = None,
                    participants: list[str] | None = None) -> tuple[pl.DataFrame, dict[str, float], Unknown]:
    """A narration table as action rows (the columns of `load_annotations`), each video's
    duration (its last end), and the words no class covers. `participant` is used for rows
    without a `participant` column (or value); a row with neither is an error."""
    path = Path(path)
    raw = _read_table(path)
    missing = [c for c in REQUIRED if c not in raw.columns]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(missing)}; a narration table has video_id, start, "
                        f"end, text and optionally participant (has: {', '.join(c for c in raw.columns if c != '__row')})")
    if "participant" not in raw.columns and participant is None:
        raise DataError(f"{path}: no 'participant' column; say whose memory this is with --participant P01")
    reader = reader or NarrationReader()
    unknown = Unknown()
    records = []
    first_row = "__row" not in raw.columns
    for n, r in enumerate(raw.iter_rows(named=True)):
        line = r.get("__row") or (n + 2 if first_row and path.suffix.lower() in (".csv", ".tsv") else n + 1)
        where = f"{path}: row {line}"
        who = r.get("participant") or participant
        if who is None:
            raise DataError(f"{where}, field 'participant': empty, and no --participant given")
        video, start, end, text = check_moment(where, r["video_id"], r["start"], r["end"], r["text"], who)
        if participants is not None and who not in participants:
            continue
        reading = reader.read(text)
        unknown.add(reading)
        records.append(reader.action(reading, who, video, start, end, narration_id=f"{video}_{n}", row=line))
    df = pl.DataFrame(records, schema=ACTION_SCHEMA, orient="row") if records else pl.DataFrame(schema=ACTION_SCHEMA)
    df = df.sort(["video_id", "start_s", "stop_s", "row"])
    durations = dict(df.group_by("video_id").agg(pl.col("stop_s").max()).iter_rows()) if df.height else {}
    return df, durations, unknown

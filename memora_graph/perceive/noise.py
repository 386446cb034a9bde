"""Imperfect perception: inject known errors, at known rates, into the narrated actions.

Perception from narrations is deterministic, so a perceiver's errors can be simulated before it
runs: `inject_noise` rewrites the checked action rows (`load_annotations`) the way a worse
perceiver would have reported them, logs every error it made with an id, and `write_noisy`
writes the result as an EPIC-style annotation folder that `memora build --annotations` reads.
Every layer of a segment (summary, action breakdown, objects, places, states) then carries the
error consistently, because the segment encoder reads the altered row.

Error types (each at its own rate, per its own unit):

    drop     an object mention is missed (unit: a noun of an action; an action whose only
             object is missed is lost with it)
    swap     a noun is confused with another of the same EPIC category (noun_classes.csv
             `category`), drawn by how often that noun is narrated (unit: a noun)
    verb     a verb is confused with another of its family (verb_classes.csv `category`)
             (unit: an action)
    alias    one object is named two ways within a video: from a random mention on (its own name
             used at least once, the second at least twice), it goes by a confusable name of its
             category (unit: an object of a video, its noun class, mentioned 3+ times)
    state    a state change is missed: the action is reported as 'use' (no state) instead of
             a state-changing verb (unit: an action whose verb changes a state)
    time     start and stop shift by up to +-delta seconds (unit: an action)
    segment  a whole 10 s segment is missed (unit: a segment with narrated actions)

`mixed` applies every type at the same rate. Draws come from `random.Random` seeded with
(seed, type, video), so a run is reproducible and one type's draws do not depend on another's
rate. The error log (`errors.jsonl`) has one line per error: id, type, participant, video,
narration_id, time, what was reported before and after.
"""

from __future__ import annotations

import csv
import json
import math
import random
import re
import shutil
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

import polars as pl

from memora_graph.errors import DataError
from memora_graph.files import staged_files
from memora_graph.perceive.annotations import REQUIRED_COLUMNS, ClassTables, noun_phrase
from memora_graph.perceive.vocab import NON_OBJECTS, PLACE_NOUNS, VERB_STATE

ERROR_TYPES = ("drop", "swap", "verb", "alias", "state", "time", "segment")
MIXED = "mixed"
DEFAULT_DELTA = 5.0  # seconds: half a segment
NO_STATE_VERB = "use"  # verb class key of an action whose state change was missed
TURN_SECONDS = 10.0
ALIAS_MIN_MENTIONS = 3  # an object named once by its own name and at least twice by a second one
ALIAS_CONSISTENCY = 0.8  # measuring: the share of later mentions under the second name that makes an alias
FPS = 50.0


@dataclass(frozen=True)
class NoiseSpec:
    """The rate of each error type (0..1) and the time shift bound; `seed` fixes every draw."""

    rates: dict[str, float] = field(default_factory=dict)
    delta: float = DEFAULT_DELTA
    seed: int = 0

    def __post_init__(self) -> None:
        for k, v in self.rates.items():
            if k not in ERROR_TYPES:
                raise DataError(f"unknown error type {k!r}; known: {', '.join(ERROR_TYPES)} (or {MIXED})")
            if not (isinstance(v, (int, float)) and 0 <= v <= 1):
                raise DataError(f"the rate of {k!r} must lie between 0 and 1 (got {v!r})")
        if not (math.isfinite(self.delta) and self.delta >= 0):
            raise DataError(f"the time shift bound delta must be a non-negative number of seconds (got {self.delta!r})")

    @classmethod
    def of(cls, error: str, rate: float, delta: float = DEFAULT_DELTA, seed: int = 0) -> NoiseSpec:
        """One error type at `rate`, or every type at `rate` for 'mixed'."""
        if error == MIXED:
            return cls({t: rate for t in ERROR_TYPES}, delta, seed)
        return cls({error: rate}, delta, seed)

    def rate(self, error: str) -> float:
        return float(self.rates.get(error, 0.0))

    @property
    def clean(self) -> bool:
        return not any(self.rates.values())


@dataclass
class NoiseResult:
    actions: pl.DataFrame  # the noisy rows, columns of load_annotations
    errors: list[dict]  # one per injected error (see the module doc)
    units: dict[str, int]  # how many units each type could have hit

    def counts(self) -> dict[str, int]:
        c = Counter(e["type"] for e in self.errors)
        return {t: c.get(t, 0) for t in ERROR_TYPES}


class _Confusions:
    """Who can be mistaken for whom: nouns within their EPIC category (places with places,
    movable objects with movable objects), verbs within their family; drawn by how often each is
    narrated in the rows at hand, so a plate becomes a bowl more often than a saucer."""

    def __init__(self, classes: ClassTables, verb_family: dict[int, str], df: pl.DataFrame):
        noun_freq: Counter[int] = Counter(c for cs in df["all_noun_classes"].to_list() for c in cs)
        verb_freq: Counter[int] = Counter(df["verb_class"].to_list())
        self.classes = classes
        self.nouns: dict[tuple[str, bool], list[tuple[int, int]]] = {}
        for c, n in sorted(noun_freq.items()):
            key = classes.nouns.get(c, "")
            if key in NON_OBJECTS or not classes.noun_category.get(c):
                continue
            self.nouns.setdefault((classes.noun_category[c], key in PLACE_NOUNS), []).append((c, n))
        self.verbs: dict[str, list[tuple[int, int]]] = {}
        for c, n in sorted(verb_freq.items()):
            if verb_family.get(c):
                self.verbs.setdefault(verb_family[c], []).append((c, n))
        self.verb_family = verb_family

    def noun(self, cls: int, rng: random.Random) -> int | None:
        key = self.classes.nouns.get(cls, "")
        pool = [(c, n) for c, n in self.nouns.get((self.classes.noun_category.get(cls, ""), key in PLACE_NOUNS), [])
                if c != cls]
        return _weighted(pool, rng)

    def verb(self, cls: int, rng: random.Random) -> int | None:
        pool = [(c, n) for c, n in self.verbs.get(self.verb_family.get(cls, ""), []) if c != cls]
        return _weighted(pool, rng)


def _weighted(pool: list[tuple[int, int]], rng: random.Random) -> int | None:
    if not pool:
        return None
    return rng.choices([c for c, _ in pool], weights=[n for _, n in pool], k=1)[0]


def verb_families(folder: Path) -> dict[int, str]:
    """verb class id -> its EPIC family (verb_classes.csv `category`); empty where the table has none."""
    path = folder / "verb_classes.csv"
    df = pl.read_csv(path, infer_schema=False)
    if "category" not in df.columns:
        return {}
    return {int(i): c for i, c in zip(df["id"].to_list(), df["category"].to_list()) if c}


def _rng(spec: NoiseSpec, kind: str, video: str) -> random.Random:
    return random.Random(f"{spec.seed}:{kind}:{video}")


def _replace_word(text: str, old: str, new: str) -> str:
    """`old` (a noun phrase, else its head word) replaced by `new` once in `text`; `new` empty removes it."""
    for said in dict.fromkeys((old, old.split()[-1] if old.split() else old)):
        if not said:
            continue
        pattern = rf"\b{re.escape(said)}(?:e?s)?\b"
        if re.search(pattern, text, flags=re.IGNORECASE):
            out = re.sub(pattern, new, text, count=1, flags=re.IGNORECASE)
            return re.sub(r"\s{2,}", " ", out).strip()
    return text


def inject_noise(actions: pl.DataFrame, classes: ClassTables, spec: NoiseSpec, durations: dict[str, float],
                 verb_family: dict[int, str]) -> NoiseResult:
    """The rows a perceiver with the error rates of `spec` would have reported (see the module doc).
    `actions` are `load_annotations` rows; `durations` bound shifted times to each video."""
    conf = _Confusions(classes, verb_family, actions)
    use_cls = next((c for c, k in classes.verbs.items() if k == NO_STATE_VERB), None)
    errors: list[dict] = []
    units: Counter[str] = Counter()
    out_rows: list[dict] = []

    def log(kind: str, row: dict, before, after, **extra) -> None:
        errors.append({"id": f"{kind}-{len(errors):06d}", "type": kind, "participant": row["participant_id"],
                       "video": row["video_id"], "narration_id": row["narration_id"],
                       "t": round(float(row["start_s"]), 2), "before": before, "after": after, **extra})

    for video in sorted(actions["video_id"].unique().to_list()):
        rows = actions.filter(pl.col("video_id") == video).sort("start_s", "stop_s", "narration_id").to_dicts()
        # segment: whole 10 s windows missed
        turns = sorted({int(r["start_s"] // TURN_SECONDS) for r in rows})
        units["segment"] += len(turns)
        rng = _rng(spec, "segment", video)
        lost = {t for t in turns if rng.random() < spec.rate("segment")}
        for t in sorted(lost):
            gone = [r for r in rows if int(r["start_s"] // TURN_SECONDS) == t]
            log("segment", gone[0], " | ".join(r["narration"] for r in gone), "", turn=t,
                actions=[r["narration_id"] for r in gone])
        rows = [r for r in rows if int(r["start_s"] // TURN_SECONDS) not in lost]
        # alias: an object of this video goes by a second name from a random mention on
        rng = _rng(spec, "alias", video)
        mentions: dict[int, list[int]] = {}
        for i, r in enumerate(rows):
            for c in dict.fromkeys(r["all_noun_classes"]):
                if classes.nouns.get(c, "") not in NON_OBJECTS and classes.nouns.get(c, "") not in PLACE_NOUNS:
                    mentions.setdefault(c, []).append(i)
        alias_from: dict[int, tuple[int, int]] = {}  # true class -> (first aliased row, alias class)
        for c in sorted(mentions):
            if len(mentions[c]) < ALIAS_MIN_MENTIONS:
                continue  # too few mentions to be named two ways
            units["alias"] += 1
            if rng.random() < spec.rate("alias"):
                other = conf.noun(c, rng)
                if other is not None:
                    alias_from[c] = (mentions[c][rng.randrange(1, len(mentions[c]) - 1)], other)
        rng_drop, rng_swap = _rng(spec, "drop", video), _rng(spec, "swap", video)
        rng_verb, rng_state, rng_time = _rng(spec, "verb", video), _rng(spec, "state", video), _rng(spec, "time", video)
        for i, r in enumerate(rows):
            r = dict(r, all_nouns=list(r["all_nouns"]), all_noun_classes=list(r["all_noun_classes"]))
            first_error = len(errors)
            changed = dropped = False
            # nouns: alias, then swap, then drop (each mention on its own)
            nouns, ncls = [], []
            for surface, c in zip(r["all_nouns"], r["all_noun_classes"]):
                key = classes.nouns.get(c, surface)
                if key in NON_OBJECTS:
                    nouns.append(surface)
                    ncls.append(c)
                    continue
                if c in alias_from and i >= alias_from[c][0]:
                    new = alias_from[c][1]
                    log("alias", r, key, classes.nouns[new], true_class=c, alias_class=new,
                        first=rows[alias_from[c][0]]["narration_id"])
                    r["narration"] = _replace_word(r["narration"], noun_phrase(surface), noun_phrase(classes.nouns[new]))
                    surface, c, changed = classes.nouns[new], new, True
                else:
                    units["swap"] += 1
                    if rng_swap.random() < spec.rate("swap"):
                        new = conf.noun(c, rng_swap)
                        if new is not None:
                            log("swap", r, key, classes.nouns[new], true_class=c, swap_class=new)
                            r["narration"] = _replace_word(r["narration"], noun_phrase(surface),
                                                           noun_phrase(classes.nouns[new]))
                            surface, c, changed = classes.nouns[new], new, True
                units["drop"] += 1
                if rng_drop.random() < spec.rate("drop"):
                    log("drop", r, classes.nouns.get(c, surface), "", noun_class=c)
                    r["narration"] = _replace_word(r["narration"], noun_phrase(surface), "")
                    changed = dropped = True
                    continue
                nouns.append(surface)
                ncls.append(c)
            if dropped and not any(classes.nouns.get(c, "") not in NON_OBJECTS for c in ncls):
                continue  # its only object was missed: the action is lost with it
            r["all_nouns"], r["all_noun_classes"] = nouns, ncls
            if ncls and (r["noun_class"] not in ncls or changed):
                r["noun_class"], r["noun"] = ncls[0], nouns[0]
            # verb: confused within its family, or its state change missed
            units["verb"] += 1
            if rng_verb.random() < spec.rate("verb"):
                new = conf.verb(r["verb_class"], rng_verb)
                if new is not None:
                    log("verb", r, r["verb_key"], classes.verbs[new], verb_class=r["verb_class"], new_class=new)
                    r = _set_verb(r, new, classes)
                    changed = True
            if r["verb_key"] in VERB_STATE and use_cls is not None:
                units["state"] += 1
                if rng_state.random() < spec.rate("state"):
                    log("state", r, VERB_STATE[r["verb_key"]], "", verb=r["verb_key"],
                        noun_class=r["all_noun_classes"][0] if r["all_noun_classes"] else r["noun_class"])
                    r = _set_verb(r, use_cls, classes)
                    changed = True
            # time: shifted by up to +-delta, within the video
            units["time"] += 1
            if rng_time.random() < spec.rate("time") and spec.delta > 0:
                shift = round(rng_time.uniform(-spec.delta, spec.delta), 2)
                end = durations.get(video, r["stop_s"])
                length = r["stop_s"] - r["start_s"]
                start = min(max(r["start_s"] + shift, 0.0), max(end - length, 0.0))
                log("time", r, round(r["start_s"], 2), round(start, 2), shift=shift)
                r["start_s"], r["stop_s"] = start, start + length
                changed = True
            for e in errors[first_error:]:
                e["t_out"] = round(float(r["start_s"]), 2)  # where the error lands after any time shift
            r["_changed"] = changed
            out_rows.append(r)
    schema = {k: v for k, v in actions.schema.items()}
    frame = pl.DataFrame([{k: r[k] for k in schema} | {"_changed": r["_changed"]} for r in out_rows],
                         schema={**schema, "_changed": pl.Boolean}) if out_rows else \
        pl.DataFrame(schema={**schema, "_changed": pl.Boolean})
    return NoiseResult(frame.sort("video_id", "start_s", "stop_s", "narration_id"), errors, dict(units))


def _set_verb(r: dict, cls: int, classes: ClassTables) -> dict:
    old, new = r["verb_key"], classes.verbs[cls]
    said = r["verb"] or old
    text = r["narration"]
    for w in dict.fromkeys((said.replace("-", " "), said.split("-")[0], old.replace("-", " "), old.split("-")[0])):
        pattern = rf"\b{re.escape(w)}\w*\b"
        if re.search(pattern, text, flags=re.IGNORECASE):
            text = re.sub(pattern, new.replace("-", " "), text, count=1, flags=re.IGNORECASE)
            break
    else:
        text = f"{new.replace('-', ' ')} {text}"
    return dict(r, verb_class=cls, verb_key=new, verb=new, narration=text)


def _timestamp(seconds: float) -> str:
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{int(h):02d}:{int(m):02d}:{s:05.2f}"


def write_noisy(out: str | Path, result: NoiseResult, meta: Path, spec: NoiseSpec, source: str = "") -> Path:
    """An EPIC-style annotation folder for `memora build --annotations OUT/annotations.csv`:
    annotations.csv, video_info.csv and the class tables (copied from `meta`), errors.jsonl (the
    error log) and noise.json (the spec and the counts). Written aside and moved into place last.
    Returns the annotations path."""
    out = Path(out)
    with staged_files(out) as aside:
        with aside("annotations.csv").open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=REQUIRED_COLUMNS)
            w.writeheader()
            for r in result.actions.iter_rows(named=True):
                start, stop = round(r["start_s"], 2), round(max(r["stop_s"], r["start_s"]), 2)
                keys_only = r["text_source"] == "class_keys" and not r["_changed"]
                w.writerow({
                    "narration_id": r["narration_id"], "participant_id": r["participant_id"], "video_id": r["video_id"],
                    "narration_timestamp": _timestamp(start), "start_timestamp": _timestamp(start),
                    "stop_timestamp": _timestamp(stop), "start_frame": str(math.floor(start * FPS)),
                    "stop_frame": str(math.floor(stop * FPS)), "narration": "" if keys_only else r["narration"],
                    "verb": r["verb"], "verb_class": str(r["verb_class"]), "noun": r["noun"],
                    "noun_class": str(r["noun_class"]), "all_nouns": repr(list(r["all_nouns"])),
                    "all_noun_classes": repr(list(r["all_noun_classes"])),
                })
        with aside("errors.jsonl").open("w") as fh:
            for e in result.errors:
                fh.write(json.dumps(e, sort_keys=True) + "\n")
        for name in ("video_info.csv", "verb_classes.csv", "noun_classes.csv"):
            shutil.copyfile(meta / name, aside(name))
        aside("noise.json").write_text(json.dumps({"spec": asdict(spec), "source": source, "counts": result.counts(),
                                                   "units": result.units, "actions": result.actions.height}, indent=1) + "\n")
    return out / "annotations.csv"


def read_errors(folder: str | Path) -> list[dict]:
    """The error log of a noisy annotation folder."""
    path = Path(folder) / "errors.jsonl"
    if not path.exists():
        raise DataError(f"{path}: no error log (written by `write_noisy`)")
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


__all__ = ["ERROR_TYPES", "MIXED", "NoiseResult", "NoiseSpec", "inject_noise", "measure_errors", "read_errors", "verb_families",
           "write_noisy"]


# -- measuring a perceiver's error rates against annotations -------------------------------------


def _object_classes(classes: ClassTables, cs) -> list[int]:
    return [c for c in cs if classes.nouns.get(c, "") not in NON_OBJECTS]


def measure_errors(reference: pl.DataFrame, perceived: pl.DataFrame, classes: ClassTables) -> dict[str, dict]:
    """A perceiver's error rate per type, measured against annotations of the same videos (both
    `load_annotations` frames): the rates `NoiseSpec` takes, so a user reads their operating point
    off the noise curves. Each perceived action is matched to the reference action of its video
    with the same narration_id, else the one it overlaps most in time (each used once).

    segment: reference 10 s windows with actions where nothing was perceived; drop: reference
    object mentions missing from the matched action (or with no matched action, outside a missed
    window); swap: a mention perceived as another noun of its category; alias: objects (a noun of
    a video mentioned twice or more) that went by one other name at least twice; verb: matched
    actions with another verb (not 'use'); state: state-changing actions perceived without a state
    ('use' or a verb with none); time: matched actions whose start differs by over 0.05 s (delta:
    the largest such shift)."""
    out: dict[str, dict] = {t: {"errors": 0, "units": 0} for t in ERROR_TYPES}
    shifts: list[float] = []
    for video in sorted(reference["video_id"].unique().to_list()):
        ref = reference.filter(pl.col("video_id") == video).sort("start_s", "narration_id").to_dicts()
        got = perceived.filter(pl.col("video_id") == video).sort("start_s", "narration_id").to_dicts()
        turns = {int(r["start_s"] // TURN_SECONDS) for r in ref}
        seen_turns = {int(g["start_s"] // TURN_SECONDS) for g in got}
        out["segment"]["units"] += len(turns)
        missed_turns = turns - seen_turns
        out["segment"]["errors"] += len(missed_turns)
        by_id = {g["narration_id"]: i for i, g in enumerate(got)}
        ref_ids = {r["narration_id"] for r in ref}
        used = {j for nid, j in by_id.items() if nid in ref_ids}  # matched by id, or to none
        match: dict[int, int] = {}
        for i, r in enumerate(ref):
            j = by_id.get(r["narration_id"])
            if j is None:
                best = 0.0
                for k, g in enumerate(got):
                    if k in used:
                        continue
                    overlap = min(r["stop_s"], g["stop_s"]) - max(r["start_s"], g["start_s"])
                    span = max(r["stop_s"], g["stop_s"]) - min(r["start_s"], g["start_s"])
                    iou = overlap / span if span > 0 else float(overlap >= 0)
                    if iou > best:
                        best, j = iou, k
            if j is not None:
                used.add(j)
                match[i] = j
        said: dict[int, list[int | None]] = {}  # reference object -> what each mention was perceived as
        mentions: Counter[int] = Counter()
        for i, r in enumerate(ref):
            objs = _object_classes(classes, r["all_noun_classes"])
            mentions.update(set(objs))
            if i not in match:
                if int(r["start_s"] // TURN_SECONDS) not in missed_turns:
                    out["drop"]["units"] += len(objs)
                    out["drop"]["errors"] += len(objs)
                continue
            g = got[match[i]]
            mine = _object_classes(classes, g["all_noun_classes"])
            extra = [c for c in mine if c not in objs]
            for c in objs:
                out["drop"]["units"] += 1
                out["swap"]["units"] += 1
                if c in mine:
                    said.setdefault(c, []).append(None)
                    continue
                same = [x for x in extra if classes.noun_category.get(x) == classes.noun_category.get(c)]
                if same:
                    extra.remove(same[0])
                    said.setdefault(c, []).append(same[0])
                else:
                    out["drop"]["errors"] += 1
            out["verb"]["units"] += 1
            if g["verb_class"] != r["verb_class"] and g["verb_key"] != NO_STATE_VERB:
                out["verb"]["errors"] += 1
            if r["verb_key"] in VERB_STATE:
                out["state"]["units"] += 1
                out["state"]["errors"] += g["verb_key"] not in VERB_STATE
            out["time"]["units"] += 1
            shift = g["start_s"] - r["start_s"]
            if abs(shift) > 0.05:
                out["time"]["errors"] += 1
                shifts.append(abs(shift))
        movable = {c: n for c, n in mentions.items() if classes.nouns.get(c, "") not in PLACE_NOUNS}
        out["alias"]["units"] += sum(1 for n in movable.values() if n >= ALIAS_MIN_MENTIONS)
        for c, names in said.items():
            subs = [x for x in names if x is not None]
            if not subs:
                continue
            top, n = Counter(subs).most_common(1)[0]
            after = names[names.index(top):]  # from its first use on, the second name stands for the object
            if movable.get(c, 0) >= ALIAS_MIN_MENTIONS and n >= 2 and after.count(top) >= ALIAS_CONSISTENCY * len(after):
                out["alias"]["errors"] += 1
                out["swap"]["errors"] += len(subs) - n
            else:
                out["swap"]["errors"] += len(subs)
    for v in out.values():
        v["rate"] = round(v["errors"] / v["units"], 4) if v["units"] else None
    out["time"]["delta"] = round(max(shifts), 2) if shifts else 0.0
    return out

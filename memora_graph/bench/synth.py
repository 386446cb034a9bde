"""Long-horizon participants: an annotation file of N hours made by replaying one person's videos.

The bundled data has 2-4 hours per person; a home robot accumulates thousands. `synthesize`
replays a participant's EPIC-KITCHENS videos back to back, one replay per synthetic video
(each source video shifted to start where the previous one ended), under new video ids, and
varies every replay after the first so that memory keeps growing rather than repeating
exactly:

- renaming: a share of the object nouns of the replay get a colour and a size ("plate" ->
  "plate:red:small", read "small red plate"; its narration says so too), a new object to the
  entity editor;
- reordering: a share of actions swap their content with the next action of the same video,
  each keeping its own time slot (times stay monotone).

Every choice is drawn from `random.Random(seed, replay)`, so the same arguments give the same
file, and a longer file starts with the same replays as a shorter one. The output folder is an
EPIC-style annotation set `memora build --annotations DIR/annotations.csv` reads: annotations.csv,
video_info.csv, the class tables, and synth.json recording what was made.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import random
import re
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

from memora_graph.errors import DataError
from memora_graph.files import staged_files
from memora_graph.paths import default_annotations
from memora_graph.perceive.annotations import REQUIRED_COLUMNS, load_annotations, load_video_info, noun_phrase
from memora_graph.perceive.vocab import NON_OBJECTS, PLACE_NOUNS

# A renamed object gets a colour and a size ("plate" -> "plate:red:small", read "small red plate"):
# perception keys an object's identity on its colour, size and material (narration.py), so it is a
# new object to the entity editor, not another name of the old one. 176 pairs per noun.
COLORS = ("black", "white", "red", "green", "blue", "yellow", "silver", "grey", "brown", "pink", "orange", "purple",
          "gold", "transparent", "clear", "gray")
SIZES = ("small", "big", "large", "little", "medium", "mini", "tiny", "huge", "tall", "long", "short")
QUALIFIERS = tuple(f"{c}:{z}" for c in COLORS for z in SIZES)
LAST_VIDEO = 999  # synthetic video ids follow the participant's own (P01_110, P01_111, ...), in three digits
# so that they sort as numbers, and never reuse a source id (a bank may hold both)
FPS = 50.0
MAX_HOURS_PER_VIDEO = 23.0  # a video stays under annotations.MAX_VIDEO_SECONDS (24 h)


@dataclass
class SynthResult:
    participant: str
    hours: float
    seed: int
    rename_share: float
    reorder_share: float
    source: str
    source_sha256: str
    source_hours: float
    replays: int
    videos: int
    actions: int
    renamed: int  # actions whose object nouns were renamed
    reordered: int  # actions whose content moved to another time slot
    new_objects: list[str] = field(default_factory=list)  # "plate:red:small", ... in the order first used
    out: str = ""

    @property
    def annotations(self) -> Path:
        return Path(self.out) / "annotations.csv"


def _timestamp(seconds: float) -> str:
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{int(h):02d}:{int(m):02d}:{s:05.2f}"


def _object_nouns(df) -> list[str]:
    """The participant's movable object nouns (surface forms), sorted: places and non-objects keep their names."""
    nouns = {n for ns in df["all_nouns"].to_list() for n in ns}
    return sorted(n for n in nouns if n not in PLACE_NOUNS and n.split(":")[0] not in NON_OBJECTS
                  and n.split(":")[0] not in PLACE_NOUNS)


def first_video(videos: list[str]) -> int:
    """The number of the first synthetic video: after the participant's own (P01_109 -> 110)."""
    return max(int(v.rsplit("_", 1)[1]) for v in videos) + 1


def _head(noun: str) -> str:
    return noun.split(":")[0].replace("_", " ").replace("-", " ")


def synthesize(participant: str, hours: float, out: str | Path, seed: int = 0, rename_share: float = 0.1,
               reorder_share: float = 0.1, annotations: str | Path | None = None) -> SynthResult:
    """Write DIR/annotations.csv (+ video_info.csv, class tables, synth.json) for `hours` of video
    of `participant`, replaying their videos (see the module doc). Written aside and moved into
    place last, so an interrupted run leaves no half file under the final names."""
    if not hours > 0 or not math.isfinite(hours):
        raise DataError(f"--hours must be a positive number of hours (got {hours})")
    for name, share in (("rename share", rename_share), ("reorder share", reorder_share)):
        if not 0 <= share <= 1:
            raise DataError(f"the {name} must lie between 0 and 1 (got {share})")
    source = Path(annotations) if annotations else default_annotations()
    df = load_annotations(source, participants=[participant])
    if df.is_empty():
        raise DataError(f"{source}: no actions of participant {participant}")
    info = {v: d for v, d, _ in load_video_info(source.parent).iter_rows()}
    videos = sorted(df["video_id"].unique().to_list())
    source_seconds = sum(info[v] for v in videos)
    target = hours * 3600.0
    replays = math.ceil(target / source_seconds)
    first = first_video(videos)
    per_video = max(1, math.ceil(replays / (LAST_VIDEO - first + 1)))
    if per_video * source_seconds > MAX_HOURS_PER_VIDEO * 3600:
        raise DataError(f"{hours} h of {participant} needs more than {LAST_VIDEO - first + 1} synthetic videos of "
                        f"at most {MAX_HOURS_PER_VIDEO:g} h; ask for fewer hours")
    by_video = {v: list(df.filter(df["video_id"] == v).iter_rows(named=True)) for v in videos}
    objects = _object_nouns(df)
    n_rename = round(rename_share * len(objects))

    rows: list[dict] = []
    durations: dict[str, float] = {}  # synthetic video -> its length (s)
    new_objects: dict[str, None] = {}
    renamed = reordered = 0
    total, offset, done = 0.0, 0.0, False
    for replay in range(replays):
        rng = random.Random(f"{seed}:{participant}:{replay}")
        rename = {} if replay == 0 else {n: f"{n}:{q}" for n, q in zip(
            rng.sample(objects, n_rename), rng.choices(QUALIFIERS, k=n_rename))}
        vid = f"{participant}_{first + replay // per_video}"
        if replay % per_video == 0:
            offset = 0.0  # a new synthetic video
        for source_video in videos:
            acts = by_video[source_video]
            content = list(range(len(acts)))
            if replay > 0 and len(acts) > 1:
                for i in sorted(rng.sample(range(len(acts) - 1), round(reorder_share * (len(acts) - 1)))):
                    content[i], content[i + 1] = content[i + 1], content[i]
            remaining = target - total
            for i, src in enumerate(content):
                slot, a = acts[i], acts[src]
                if slot["start_s"] >= remaining:
                    break
                start = offset + slot["start_s"]
                row = _row(participant, vid, len(rows), start, start + a["stop_s"] - a["start_s"], a, rename)
                rows.append(row)
                durations[vid] = max(durations.get(vid, 0.0), row["_stop"])
                reordered += src != i
                used = [rename[n] for n in a["all_nouns"] if n in rename]
                renamed += bool(used)
                new_objects.update(dict.fromkeys(used))
            length = min(info[source_video], remaining)
            offset, total = offset + length, total + length
            durations[vid] = max(durations.get(vid, 0.0), offset)
            if total >= target:
                done = True
                break
        if done:
            break
    video_rows = sorted(durations.items())
    result = SynthResult(
        participant=participant, hours=hours, seed=seed, rename_share=rename_share, reorder_share=reorder_share,
        source=str(source), source_sha256=hashlib.sha256(source.read_bytes()).hexdigest(),
        source_hours=round(source_seconds / 3600, 3), replays=replay + 1, videos=len(video_rows), actions=len(rows),
        renamed=renamed, reordered=reordered, new_objects=list(new_objects), out=str(out))
    _write(Path(out), source.parent, rows, video_rows, result)
    return result


def _row(participant: str, video: str, n: int, start: float, stop: float, a: dict, rename: dict[str, str]) -> dict:
    nouns = [rename.get(x, x) for x in a["all_nouns"]]
    narration = a["narration"]
    for old in a["all_nouns"]:
        if old in rename:  # "take plate" -> "take small red plate" (the first mention)
            color, size = rename[old].split(":")[-2:]
            for said in (noun_phrase(old), _head(old)):  # "pot holder", else "holder" (or "holders")
                pattern = rf"\b{re.escape(said)}(?:e?s)?\b"
                if re.search(pattern, narration):
                    narration = re.sub(pattern, lambda m: f"{size} {color} {m.group(0)}", narration, count=1)
                    break
    start_r, stop_r = round(start, 2), round(max(stop, start), 2)
    return {
        "narration_id": f"{video}_{n}", "participant_id": participant, "video_id": video,
        "narration_timestamp": _timestamp(start_r), "start_timestamp": _timestamp(start_r),
        "stop_timestamp": _timestamp(stop_r), "start_frame": str(round(start_r * FPS)),
        "stop_frame": str(round(stop_r * FPS)), "narration": narration, "verb": a["verb"],
        "verb_class": str(a["verb_class"]), "noun": rename.get(a["noun"], a["noun"]), "noun_class": str(a["noun_class"]),
        "all_nouns": repr(nouns), "all_noun_classes": repr(list(a["all_noun_classes"])), "_stop": stop_r,
    }


def _write(out: Path, meta: Path, rows: list[dict], videos: list[tuple[str, float]], result: SynthResult) -> None:
    with staged_files(out) as aside:
        with aside("annotations.csv").open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=REQUIRED_COLUMNS, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
        with aside("video_info.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["video_id", "duration", "fps", "resolution"])
            w.writerows([(v, f"{math.ceil(d * 100) / 100:.2f}", f"{FPS:g}", "1920x1080") for v, d in videos])
        for name in ("verb_classes.csv", "noun_classes.csv"):
            shutil.copyfile(meta / name, aside(name))
        aside("synth.json").write_text(json.dumps(asdict(result), indent=1) + "\n")


__all__ = ["QUALIFIERS", "SynthResult", "first_video", "synthesize"]

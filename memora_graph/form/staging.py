"""Finished videos of a build in progress, on disk: `BANK/.staging/<participant>/<seq>_<video>/`.

A build edits video after video in memory and bulk-loads them all at the end; each finished
video is staged so that a killed build resumes after it. A staged video is a directory of
Arrow IPC files (its graph rows, one file per table, and the editor's registry after it:
entities and places) plus `counters.json`, and `index.json`, written last, with the sha256 and
size of every other file. The directory is written under a temporary name and renamed into
place, so it is there whole or not at all.

Nothing here can carry code: Arrow IPC holds typed columns and JSON holds numbers. A staged
video whose index is missing or unreadable, whose files differ from their recorded hashes, or
that holds a file its index does not list is not loaded; it and the videos staged after it
(they were edited on top of its registry) are built again. Files in the staging folder that are
not staged videos (e.g. a planted `.pkl`) are never opened; `memora verify` lists them.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from memora_graph.errors import DataError

FORMAT = 1
INDEX = "index.json"
COUNTERS = "counters.json"
SNAPSHOT_TABLES = ("_entities", "_places")  # the editor's registry after the video
_DIR = re.compile(r"^(\d{4})_([^/\\\x00]+)$")
_FILE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*\.arrow$|^counters\.json$")
log = logging.getLogger("memora_graph.integrity")


def sha256_file(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


@dataclass
class StagedVideo:
    seq: int
    video: str
    path: Path

    def _bytes(self, name: str) -> bytes:
        """A file's bytes, checked against the index again as they are read."""
        listed = json.loads((self.path / INDEX).read_text())["files"]
        data = (self.path / name).read_bytes()
        if name not in listed or hashlib.sha256(data).hexdigest() != listed[name]["sha256"]:
            raise StagingError(f"{self.path / name}: changed since the build checked it (sha256 differs)")
        return data

    def _frame(self, name: str) -> pl.DataFrame:
        return pl.read_ipc(io.BytesIO(self._bytes(name)))

    def frame(self, table: str) -> pl.DataFrame | None:
        """One table's rows of the video (None when it has none): a bulk load reads a table at a
        time, so a long build never holds every staged row at once."""
        if table in SNAPSHOT_TABLES or not (self.path / f"{table}.arrow").exists():
            return None
        return self._frame(f"{table}.arrow")

    def snapshot(self) -> tuple[pl.DataFrame, pl.DataFrame, dict]:
        """(entities, places, counters) of the editor after this video."""
        counters = json.loads(self._bytes(COUNTERS))
        return self._frame("_entities.arrow"), self._frame("_places.arrow"), counters


class StagingError(DataError):
    """A staged video changed between its check and its load."""


class Staging:
    """One participant's staging folder."""

    def __init__(self, root: Path):
        self.root = Path(root)

    def write(self, seq: int, video: str, frames: dict[str, pl.DataFrame | None], entities: pl.DataFrame,
              places: pl.DataFrame, counters: dict) -> StagedVideo:
        name = f"{seq:04d}_{video}"
        if not _DIR.match(name):
            raise ValueError(f"video id {video!r} cannot name a staging folder")
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = self.root / f".{name}.tmp"
        if tmp.exists():
            shutil.rmtree(tmp)
        tmp.mkdir()
        files = {}
        for table, df in {**frames, "_entities": entities, "_places": places}.items():
            if df is None:
                continue
            path = tmp / f"{table}.arrow"
            df.write_ipc(path, compression="zstd")
            files[path.name] = path
        (tmp / COUNTERS).write_text(json.dumps({k: int(v) for k, v in counters.items()}, sort_keys=True))
        files[COUNTERS] = tmp / COUNTERS
        index = {"format": FORMAT, "seq": seq, "video": video,
                 "files": {n: {"sha256": sha256_file(p), "bytes": p.stat().st_size} for n, p in sorted(files.items())}}
        (tmp / INDEX).write_text(json.dumps(index, indent=1, sort_keys=True))  # last: the video is whole
        final = self.root / name
        os.replace(tmp, final)
        return StagedVideo(seq, video, final)

    def entries(self) -> list[Path]:
        """Staged-video folders, in order (verified or not)."""
        if not self.root.is_dir():
            return []
        return sorted(p for p in self.root.iterdir() if p.is_dir() and _DIR.match(p.name))

    def half_written(self) -> list[Path]:
        """Folders a killed build left half-written: a video being staged (`.NAME.tmp`) or the bulk
        load's files (`.load.tmp`). Never read; the next build of the participant removes them."""
        if not self.root.is_dir():
            return []
        return sorted(p for p in self.root.glob(".*.tmp") if p.is_dir())

    def foreign(self) -> list[Path]:
        """Everything in the folder that is neither a staged video nor a half-written folder
        (never opened by a build)."""
        if not self.root.is_dir():
            return []
        half = set(self.half_written())
        return sorted(p for p in self.root.iterdir() if not (p.is_dir() and _DIR.match(p.name)) and p not in half)

    @staticmethod
    def check(path: Path) -> str | None:
        """Why a staged-video folder cannot be loaded, or None when every file matches its index."""
        try:
            index = json.loads((path / INDEX).read_text())
            listed = index["files"]
            if index.get("format") != FORMAT or f"{int(index['seq']):04d}_{index['video']}" != path.name:
                return "its index does not describe this folder"
        except FileNotFoundError:
            return f"no {INDEX} (written last: the video was not finished)"
        except (OSError, ValueError, KeyError, TypeError) as exc:
            return f"unreadable {INDEX} ({exc})"
        present = {p.name for p in path.iterdir()} - {INDEX}
        if present != set(listed):
            extra, missing = sorted(present - set(listed)), sorted(set(listed) - present)
            return ", ".join(filter(None, [f"files not in its index: {', '.join(extra)}" if extra else "",
                                           f"missing: {', '.join(missing)}" if missing else ""]))
        for name, meta in listed.items():
            if not _FILE.match(name):
                return f"its index lists an unexpected file {name!r}"
            f = path / name
            if not f.is_file() or f.stat().st_size != meta.get("bytes") or sha256_file(f) != meta.get("sha256"):
                return f"{name} does not match the sha256 in its index (damaged or edited)"
        if "_entities.arrow" not in listed or "_places.arrow" not in listed or COUNTERS not in listed:
            return "no registry snapshot"
        return None

    def load(self, skip: set[str]) -> tuple[list[StagedVideo], list[tuple[Path, str]]]:
        """The staged videos a build can resume from, in order, and the (folder, reason) of those
        it must build again. Videos in `skip` (already in the database) are removed. The first
        video that fails its check is dropped with every later one."""
        good, dropped = [], []
        for path in self.entries():
            m = _DIR.match(path.name)
            video = m.group(2)
            if video in skip:  # loaded by a run that died before cleaning up
                shutil.rmtree(path, ignore_errors=True)
                continue
            why = "staged after a video that is built again" if dropped else self.check(path)
            if why:
                dropped.append((path, why))
                continue
            good.append(StagedVideo(int(m.group(1)), video, path))
        for path, why in dropped:
            log.warning("%s: not loaded (%s); the video is built again", path, why)
            shutil.rmtree(path, ignore_errors=True)
        for tmp in self.half_written():
            shutil.rmtree(tmp, ignore_errors=True)  # a video being staged, or a load, when the build died
        return good, dropped

    def clear(self, staged: list[StagedVideo]) -> None:
        """Remove loaded videos, then the folder if nothing else is in it."""
        for s in staged:
            shutil.rmtree(s.path, ignore_errors=True)
        try:
            self.root.rmdir()
            self.root.parent.rmdir()  # .staging itself, when no other participant is staged
        except OSError:
            pass

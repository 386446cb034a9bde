"""A bank's manifest (BANK/manifest.json): what each write left behind, per participant (videos,
record counts, indexes, consolidation, integrity), read with every field checked and written
atomically under the manifest lock. Also the participant ids the manifest is keyed by."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

from memora_graph.bank.locks import BUILD_LOCK, manifest_lock
from memora_graph.errors import BankError
from memora_graph.ids import PARTICIPANT_ID, RULE, describe
from memora_graph.ids import is_participant_id as _is_id

MANIFEST = "manifest.json"
FORMAT = 1


def is_participant_id(name: str) -> bool:
    """Whether `name` is a participant id (memora_graph/ids.py: P01, alice, robot-7)."""
    return _is_id(name)


def parse_participants(text: object, option: str = "--participants") -> list[str] | None:
    """A comma-separated participant list ('P01,P02') as ids, or None for 'all'. An empty list
    ('', ',') is an error, not everyone."""
    if not isinstance(text, str):
        raise BankError(f"{option}: expected participant ids like P01,alice or 'all', not {text!r}")
    if text.strip().lower() == "all":
        return None
    pids = [p.strip() for p in text.split(",") if p.strip()]
    if not pids:
        raise BankError(f"{option}: no participant given (ids like P01,alice, or 'all')")
    bad = [p for p in pids if not PARTICIPANT_ID.match(p)]
    if bad:
        raise BankError(f"{option}: {describe(bad[0])} is not a participant id ({RULE})")
    return list(dict.fromkeys(pids))


def shown(value: object) -> str:
    """A manifest value as an error message names it: its JSON type and its first characters."""
    text = json.dumps(value) if isinstance(value, (str, int, float, list, dict, type(None))) else repr(value)
    return f"a JSON {type(value).__name__} {text[:60]}"


class ManifestFile:
    """The manifest of the bank in `directory`, and where its participants' databases lie."""

    def __init__(self, directory: Path):
        self.directory = directory
        self.path = directory / MANIFEST

    def exists(self) -> bool:
        return self.path.exists()

    def db_path(self, participant: str) -> Path:
        if not isinstance(participant, str) or not PARTICIPANT_ID.match(participant):
            raise BankError(f"participant must be a participant id ({RULE}), not {describe(participant)}")
        return self.directory / f"{participant}.kuzu"

    def read(self) -> dict:
        if not self.exists():
            if self.directory.is_dir() and any(self.directory.glob("*.kuzu")):
                raise BankError(f"{self.directory}: has databases but no {MANIFEST}; not a complete memora bank")
            raise BankError(f"{self.directory}: no memory bank here (no {MANIFEST}). Build one with "
                            f"`memora build {self.directory}`.")
        try:
            data = json.loads(self.path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
            raise BankError(f"{self.path}: damaged manifest ({type(exc).__name__}: {exc})") from exc
        except OSError as exc:
            raise BankError(f"{self.path}: cannot be read ({exc.strerror or exc})") from exc
        if not isinstance(data, dict):
            raise BankError(f"{self.path}: damaged manifest (a JSON {type(data).__name__}, not an object)")
        if data.get("format") != FORMAT:
            raise BankError(f"{self.path}: unknown bank format {data.get('format')!r}")
        parts = data.get("participants")
        if not isinstance(parts, dict) or not all(isinstance(k, str) and PARTICIPANT_ID.match(k) and isinstance(v, dict)
                                                  and isinstance(v.get("counts", {}), dict) for k, v in parts.items()):
            raise BankError(f"{self.path}: damaged manifest ('participants' is not a map of participant ids "
                            "to their records)")
        writing = data.get("writing", {})
        if not isinstance(writing, dict) or not all(isinstance(k, str) and PARTICIPANT_ID.match(k) and isinstance(v, dict)
                                                    for k, v in writing.items()):
            raise BankError(f"{self.path}: damaged manifest (field 'writing' is not a map of participant ids "
                            f"to write marks, but {shown(writing)})")
        for p, entry in parts.items():
            for key in ("counts", "integrity"):
                if entry.get(key) is not None and not isinstance(entry[key], dict):
                    raise BankError(f"{self.path}: damaged manifest (participants.{p}.{key} is "
                                    f"{shown(entry[key])}, not a map)")
        return data

    def init(self, mode: str, embed_model: str, consolidated: bool) -> dict:
        if self.exists():
            data = self.read()
            if data["mode"] != mode:
                raise BankError(f"{self.directory}: is a '{data['mode']}' bank; cannot add a '{mode}' build to it. "
                                "Use another directory.")
            if data["embed_model"] != embed_model:
                raise BankError(f"{self.directory}: embeddings are from {data['embed_model']}, not {embed_model}. "
                                "Use another directory.")
            return data
        self.directory.mkdir(parents=True, exist_ok=True)
        (self.directory / BUILD_LOCK).touch()
        data = {"format": FORMAT, "mode": mode, "embed_model": embed_model, "consolidated": consolidated, "participants": {}}
        self.write(data)
        return data

    def write(self, data: dict) -> None:
        tmp = self.path.with_suffix(".json.tmp")
        try:
            tmp.write_text(json.dumps(data, indent=2, sort_keys=True))
        except OSError:
            tmp.unlink(missing_ok=True)
            raise
        os.replace(tmp, self.path)  # atomic: never a half-written manifest

    def update(self, change: Callable[[dict], None]) -> dict:
        """Read, change and write the manifest under its lock."""
        with manifest_lock(self.directory):
            data = self.read()
            before = json.dumps(data, sort_keys=True)
            change(data)
            if json.dumps(data, sort_keys=True) != before:  # an unchanged manifest is not rewritten
                self.write(data)
        return data

    def record_participant(self, participant: str, videos: list[str], counts: dict,
                           annotations: dict[str, str] | None = None, extra: dict | None = None) -> None:
        """Record what a build wrote. `annotations`: per video, the fingerprint of the rows it was
        built from (a later build tells when they changed). `extra` sets entry fields a build
        leaves to later steps (`consolidated`, `inferred`, `indexes`): an import brings them along."""
        def change(data: dict) -> None:
            entry = {"db": f"{participant}.kuzu", "videos": sorted(videos), "counts": dict(counts)}
            old = data["participants"].get(participant, {})
            # the database keeps its indexes and its inferred knowledge (until consolidation runs again)
            entry.update({k: old[k] for k in ("indexes", "consolidated", "inferred", "integrity") if k in old})
            for k in ("routines", "preferences"):
                if k in old.get("counts", {}) and k not in counts:
                    entry["counts"][k] = old["counts"][k]
            fingerprints = {**old.get("annotations", {}), **(annotations or {})}
            if fingerprints:
                entry["annotations"] = {v: fingerprints[v] for v in sorted(fingerprints) if v in entry["videos"]}
            extra_fields = dict(extra or {})
            indexes = extra_fields.pop("indexes", None)
            entry.update(extra_fields)
            data["participants"][participant] = entry
            if indexes is not None:
                self.set_indexes(data, participant, indexes)
            if "consolidated" in extra_fields:
                self.set_condition(data)

        self.update(change)

    @staticmethod
    def set_condition(data: dict) -> None:
        """The bank-level condition in a manifest `data`, from its participants' `consolidated`:
        memora_full when all are, memora_episodic when none is, else mixed."""
        flags = [e.get("consolidated", False) for e in data["participants"].values()]
        data["consolidated"] = bool(flags) and all(flags)
        data["condition"] = "memora_full" if data["consolidated"] else ("memora_episodic" if not any(flags) else "mixed")

    @staticmethod
    def set_indexes(data: dict, participant: str, names: list[str]) -> None:
        """Record in a manifest `data` the indexes a participant's database has, and per kind
        whether every participant has all of them (`data["indexes"]`, e.g. {"fts": false})."""
        from memora_graph.store import INDEX_KINDS, index_names

        entry = data["participants"].get(participant)
        if entry is not None:
            entry["indexes"] = sorted(names)
        parts = data["participants"].values()
        data["indexes"] = {kind: bool(parts) and all(set(index_names(kind)) <= set(e.get("indexes", [])) for e in parts)
                           for kind in INDEX_KINDS}

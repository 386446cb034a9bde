"""The records of files derived from a participant's database (the persisted tool stores, the
baseline caches, the kept consolidation folds), kept in the bank's manifest next to the
database's own integrity record, so that a file derived from a database is trusted only when
its sha256 is the one the manifest recorded for it. A record beside the files (a store's
meta.json) can be rewritten by whoever edits them; the manifest is the record every open of
the database already trusts.

A participant's entry holds `derived: {name: record}`; a record carries `of`, what it was
derived from (the database's recorded sha256, or a cache key), and the sha256 of its files.
Bank-wide derived files (the embedding cache every participant shares) are under the
manifest's top-level `derived`. A record is written under the manifest lock, and only while
the database is still the one it was derived from: a write that lands meanwhile leaves it
unrecorded (so unused, and computed again), never recorded for the wrong database."""

from __future__ import annotations

import hashlib
from pathlib import Path

from memora_graph.bank.manifest import ManifestFile

FIELD = "derived"


def sha256_file(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def recorded(record: dict | None, of: str, files: dict[str, bytes]) -> bool:
    """Whether `record` (from `DerivedFiles.get`) was derived from `of` and holds the sha256 of
    each of `files` (name -> bytes, as read): whether those bytes may be trusted."""
    if not isinstance(record, dict) or record.get("of") != of or not isinstance(record.get("files"), dict):
        return False
    return all(record["files"].get(n) == sha256_bytes(b) for n, b in files.items())


class DerivedFiles:
    """The derived-file records of the bank whose manifest is `manifest`."""

    def __init__(self, manifest: ManifestFile):
        self.manifest = manifest

    @staticmethod
    def _records(data: dict, participant: str | None) -> dict:
        holder = data if participant is None else data.get("participants", {}).get(participant)
        got = holder.get(FIELD) if isinstance(holder, dict) else None
        return got if isinstance(got, dict) else {}

    def get(self, participant: str | None, name: str, data: dict | None = None) -> dict | None:
        """The record `name` of `participant` (None: of the bank), or None if there is none."""
        data = data if data is not None else self.manifest.read()
        got = self._records(data, participant).get(name)
        return got if isinstance(got, dict) else None

    def get_all(self, participant: str | None, data: dict | None = None) -> dict:
        """Every record of `participant` (None: of the bank), by name."""
        return dict(self._records(data if data is not None else self.manifest.read(), participant))

    def put(self, participant: str | None, name: str, record: dict, db_sha256: str | None = None) -> bool:
        """Record `record` as `name`, under the manifest lock. With `db_sha256`: only while the
        participant's database is still recorded with that sha256 (else nothing is written and
        False returned). Raises OSError where the manifest cannot be written (a read-only bank)."""
        done = []

        def change(data: dict) -> None:
            if participant is None:
                holder = data
            else:
                holder = data["participants"].get(participant)
                if holder is None:
                    return
                if db_sha256 is not None and (holder.get("integrity") or {}).get("sha256") != db_sha256:
                    return
            records = holder.get(FIELD)
            if not isinstance(records, dict):
                records = holder[FIELD] = {}
            records[name] = record
            done.append(True)

        self.manifest.update(change)
        return bool(done)

    def drop(self, participant: str | None, name: str) -> None:
        def change(data: dict) -> None:
            holder = data if participant is None else data["participants"].get(participant)
            if isinstance(holder, dict) and isinstance(holder.get(FIELD), dict):
                holder[FIELD].pop(name, None)
                if not holder[FIELD]:
                    holder.pop(FIELD)

        self.manifest.update(change)

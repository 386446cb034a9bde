"""Moving one participant's memory between the bank and a task's scratch space.

The driver takes a `snapshot` of what the bank holds of a participant (its database with any
log or shadow file, its staged videos, its manifest entry and unfinished-write mark); a task
unpacks it into a scratch bank (`open_scratch`), where the ordinary library code builds or
consolidates it exactly as it would in the bank (an interrupted build resumes there as it
would here); `seal` hands back the closed database and the manifest entry the library wrote
for it (counts, videos, annotation fingerprints, inferred knowledge, indexes, integrity hash);
the driver `install`s both: the file replaces the bank's atomically, and the entry goes into
manifest.json under its lock. Until the entry is written, the participant carries an
unfinished-build mark, so a driver killed between the two steps leaves a participant the next
build resumes, never a database that disagrees with its record.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
import uuid
from pathlib import Path

from memora_graph.bank import Bank
from memora_graph.errors import BankError
from memora_graph.files import side_files

STAGING = ".staging"


def snapshot(bank: Bank, participant: str) -> dict:
    """What the bank holds of a participant, as plain data a task can receive."""
    data = bank.manifest()
    files: dict[str, bytes] = {}
    for f in sorted(bank.path.glob(f"{participant}.kuzu*")):
        if f.is_file():
            files[f.name] = f.read_bytes()
    staging = bank.path / STAGING / participant
    if staging.is_dir():
        for f in sorted(staging.rglob("*")):
            if f.is_file():
                files[str(Path(STAGING) / participant / f.relative_to(staging))] = f.read_bytes()
    manifest = {k: data[k] for k in ("format", "mode", "embed_model") if k in data}
    manifest.update(consolidated=False, participants={})
    if participant in data["participants"]:
        manifest["participants"][participant] = data["participants"][participant]
    mark = data.get("writing", {}).get(participant)
    if mark:  # an unfinished write: the scratch build resumes it, as a build in the bank would
        manifest["writing"] = {participant: {**mark, "pid": None, "failed_in": mark.get("pid")}}
    return {"participant": participant, "manifest": manifest, "files": files}


def open_scratch(snap: dict, root: str | None = None) -> Bank:
    """A scratch bank holding one participant's snapshot, in a new temporary directory."""
    import json

    path = Path(tempfile.mkdtemp(prefix=f"memora-{snap['participant']}-", dir=root))
    for name, blob in snap["files"].items():
        target = path / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(blob)
    (path / "manifest.json").write_text(json.dumps(snap["manifest"], indent=2, sort_keys=True))
    (path / ".build.lock").touch()
    return Bank(path)


def seal(scratch: Bank, participant: str, shared: str | None = None) -> dict:
    """The finished participant of a scratch bank: its manifest entry and its database file
    (bytes, or a path under `shared` that the driver can read)."""
    data = scratch.manifest()
    db = scratch.db_path(participant)
    if data.get("writing", {}).get(participant):
        raise BankError(f"{db}: the task left its write unfinished; not handed back")
    sides = side_files(db)
    if sides:
        raise BankError(f"{sides[0]}: left next to the finished database; not handed back")
    entry = data["participants"].get(participant)
    if not entry or not entry.get("integrity"):
        raise BankError(f"{db}: no manifest entry with an integrity record; not handed back")
    out = {"participant": participant, "entry": entry}
    if shared:
        folder = Path(shared)
        folder.mkdir(parents=True, exist_ok=True)
        target = folder / f".{participant}.kuzu.{uuid.uuid4().hex}"
        shutil.copyfile(db, target)
        out["path"] = str(target)
    else:
        out["bytes"] = db.read_bytes()
    return out


def install(bank: Bank, participant: str, sealed: dict) -> None:
    """Put a sealed participant into the bank: the file is written next to the database, checked
    against the hash its entry records, and renamed over it; then the entry is written to the
    manifest under its lock and the unfinished-build mark cleared, as a local build leaves them.
    The caller holds the participant's build lock."""
    entry = sealed["entry"]
    integ = entry["integrity"]
    db = bank.db_path(participant)
    for stale in bank.path.glob(f".{participant}.kuzu.incoming-*"):  # a killed driver's: we hold the lock
        stale.unlink(missing_ok=True)
    part = bank.path / f".{participant}.kuzu.incoming-{os.getpid()}"
    try:
        with _incoming(bank.path, part, sealed) as (size, digest, name_it):
            if size != integ.get("bytes") or digest != integ.get("sha256"):
                raise BankError(f"{participant}: the database a task handed back does not match the hash recorded "
                                "with it (damaged in transfer); the bank was not changed")
            bank.mark_writing(participant, "build")
            for side in side_files(db):  # an interrupted build's log: the new file holds everything it had
                side.unlink()
            name_it()
            os.replace(part, db)
    finally:
        part.unlink(missing_ok=True)
        if "path" in sealed:
            Path(sealed["path"]).unlink(missing_ok=True)
    shutil.rmtree(bank.path / STAGING / participant, ignore_errors=True)
    _drop_empty(bank.path / STAGING)

    def change(data: dict) -> None:
        data["participants"][participant] = entry
        marks = data.get("writing", {})
        marks.pop(participant, None)
        if not marks:
            data.pop("writing", None)
        Bank.set_indexes(data, participant, entry.get("indexes", []))
        if "consolidated" in entry:
            Bank.set_condition(data)

    bank.update_manifest(change)
    bank.remember_verified(participant, db.stat(), integ["sha256"])


@contextlib.contextmanager
def _incoming(directory: Path, part: Path, sealed: dict):
    """Write the handed-back database for `part` (same directory as the database, for an atomic
    rename), synced; yields its size, its sha256 and `name_it()`, which gives it the name `part`.
    Where the system allows it (Linux O_TMPFILE) the file has no name until `name_it()`, called
    right before the rename, so a driver killed while it is written, hashed or recorded leaves
    nothing in the bank; elsewhere it is written under `part` from the start (a later install of
    the participant removes a killed one's leftover)."""
    flag = getattr(os, "O_TMPFILE", 0)
    try:
        fd = os.open(directory, flag | os.O_RDWR, 0o644) if flag else None
    except OSError:  # a filesystem without unnamed files
        fd = None
    named = fd is None
    with open(part, "w+b") if named else os.fdopen(fd, "w+b") as fh:
        if "path" in sealed:
            with open(sealed["path"], "rb") as src:
                shutil.copyfileobj(src, fh, 1 << 20)
        else:
            fh.write(sealed["bytes"])
        fh.flush()
        os.fsync(fh.fileno())
        size = os.fstat(fh.fileno()).st_size
        fh.seek(0)
        digest = hashlib.file_digest(fh, "sha256").hexdigest()

        def name_it() -> None:
            if named:
                return
            # a directory fd makes Python call linkat, which follows the /proc link to the open
            # file (plain link() would not)
            dfd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
            try:
                os.link(f"/proc/self/fd/{fh.fileno()}", part.name, dst_dir_fd=dfd, follow_symlinks=True)
            finally:
                os.close(dfd)

        yield size, digest, name_it


def remove_scratch(scratch: Bank) -> None:
    shutil.rmtree(scratch.path, ignore_errors=True)


def _drop_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass

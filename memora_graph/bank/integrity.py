"""A bank's integrity checks: the sha256, size and rows per table recorded for each participant's
database after a write closed it (`Integrity.record`), and the checks every open runs against
that record before Kùzu reads a byte (Kùzu 0.11.3 has no page checksums: a damaged file can
return wrong values or crash the process): no unfinished write, no foreign write-ahead log, no
file the manifest does not list, the size and hash as recorded, the record counts as recorded.
`notices` tells a reader what is amiss bank-wide from a directory listing alone."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING

from memora_graph.bank.locks import WriteMarks, now, pid_alive
from memora_graph.bank.manifest import MANIFEST, PARTICIPANT_ID, ManifestFile
from memora_graph.ids import DB_FILE
from memora_graph.errors import BankError
from memora_graph.files import file_kind, file_sha256, side_files

if TYPE_CHECKING:  # imported where used: a one-shot command that reads persisted stores never loads Kùzu
    from memora_graph.store import Store

VERIFIED = ".verified.json"
NO_VERIFY_ENV = "MEMORA_NO_VERIFY"  # set by `--no-verify`; inherited by worker processes
CHECKED_COUNTS = ("segments", "entity_records", "state_events", "places")
log = logging.getLogger("memora_graph.integrity")
NOTICED: set[tuple[str, str]] = set()  # (bank, notice) already logged by this process


def verify_default() -> bool:
    return os.environ.get(NO_VERIFY_ENV, "") in ("", "0")


class VerifiedFiles:
    """A file's (device, inode, size, mtime, ctime) after it last hashed to its recorded sha256, in
    BANK/.verified.json, so that a reader need not hash an unchanged file again. Any write to
    the file, copy or swap changes ctime or the inode (ctime cannot be set back without root
    changing the clock), so changed bytes are always hashed; damage beneath the filesystem (bit
    rot) is what only `memora verify`, which always hashes, can see."""

    def __init__(self, directory: Path):
        self.directory = directory

    @staticmethod
    def stat_key(st) -> list[int]:
        return [st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]

    def read(self) -> dict:
        try:
            data = json.loads((self.directory / VERIFIED).read_text())
            return data if isinstance(data, dict) else {}
        except (OSError, ValueError):
            return {}

    def unchanged(self, participant: str, st, sha256: str | None) -> bool:
        seen = self.read().get(participant) or {}
        return bool(sha256) and seen.get("sha256") == sha256 and seen.get("stat") == self.stat_key(st)

    def remember(self, participant: str, st, sha256: str) -> None:
        seen = self.read()
        seen[participant] = {"sha256": sha256, "stat": self.stat_key(st)}
        tmp = self.directory / f"{VERIFIED}.{os.getpid()}.tmp"
        try:
            tmp.write_text(json.dumps(seen, sort_keys=True))
            os.replace(tmp, self.directory / VERIFIED)
        except OSError:  # a read-only bank: hash again next time
            tmp.unlink(missing_ok=True)

    def forget(self, participant: str) -> None:
        seen = self.read()
        if seen.pop(participant, None) is not None:
            tmp = self.directory / f"{VERIFIED}.{os.getpid()}.tmp"
            tmp.write_text(json.dumps(seen, sort_keys=True))
            os.replace(tmp, self.directory / VERIFIED)


class Integrity:
    """The integrity records and checks of the bank whose manifest is `manifest`."""

    def __init__(self, manifest: ManifestFile):
        self.manifest = manifest
        self.directory = manifest.directory
        self.verified = VerifiedFiles(manifest.directory)

    def record(self, participant: str) -> dict:
        """(Re)record a participant's integrity after any write: the sha256 and size of its
        database file and its rows per table (with the store counts), and clear the write mark.
        Call it once the database is closed (a clean close leaves no log or shadow file). Returns
        the integrity record."""
        from memora_graph.store import Store

        db = self.manifest.db_path(participant)
        sides = side_files(db)
        if sides:
            raise BankError(f"{', '.join(map(str, sides))}: still next to {db.name}; close every writer before "
                            "recording its integrity")
        with Store(db, read_only=True) as store:
            tables = store.table_counts(participant)
            counts = {k: int(v or 0) for k, v in store.rows("store_counts", participant=participant)[0].items()}
        st = db.stat()
        record = {"sha256": file_sha256(db, st), "bytes": st.st_size, "recorded_at": now(),
                  "tables": {t: v["rows"] for t, v in tables.items()},
                  "other_participant_rows": sum(v["other_participant"] for v in tables.values())}

        def change(data: dict) -> None:
            entry = data["participants"].get(participant)
            if entry is None:
                raise BankError(f"{self.manifest.path}: no entry for {participant} to record its integrity in")
            entry["counts"] = {**entry.get("counts", {}), **counts}
            entry["integrity"] = record
            WriteMarks.drop(data, participant)

        self.manifest.update(change)
        self.verified.remember(participant, st, record["sha256"])
        return record

    def check(self, participant: str, data: dict | None = None) -> None:
        """Refuse, before Kùzu touches it, a participant database whose write did not finish,
        that has a write-ahead log or shadow file it did not leave, or whose size or sha256
        differs from the manifest's record. The messages name the file and what to do."""
        data = data or self.manifest.read()
        db = self.manifest.db_path(participant)
        mark = data.get("writing", {}).get(participant)
        if mark:
            if mark.get("pid") == os.getpid():
                return  # this process is writing it (a build's consolidation step)
            raise BankError(self.interrupted_message(participant, mark))
        entry = data["participants"].get(participant)
        if entry is None:
            raise BankError(self.not_listed(participant, data))
        integ = entry.get("integrity")
        if not integ:
            raise BankError(f"{db}: {MANIFEST} records no hash for it (a bank built before integrity records?). "
                            f"`memora verify {self.directory}` checks it; `memora verify {self.directory} --accept "
                            f"{participant}` records it as it is now; or rebuild: `memora build {self.directory} "
                            f"--rebuild {participant}`.")
        self.checked_db_file(participant)
        sides = side_files(db)
        if sides:
            raise BankError(f"{sides[0]}: a {'write-ahead log' if sides[0].suffix == '.wal' else 'shadow file'} next "
                            f"to {db.name}, which was closed cleanly when its hash was recorded: it does not belong "
                            f"to this database (copied from elsewhere, or left by a write outside memora). It was not "
                            f"replayed. Move it away and retry; `memora verify {self.directory}` reports every file.")
        st = db.stat()
        digest = None
        if st.st_size == integ.get("bytes"):
            if self.verified.unchanged(participant, st, integ.get("sha256")):
                return
            digest = file_sha256(db, st)
            if digest == integ.get("sha256"):
                self.verified.remember(participant, st, digest)
                return
        owner = self.recorded_for(data, participant, st.st_size, db, st, digest)
        if owner:
            raise BankError(f"{db}: holds the database recorded for {owner} in {MANIFEST}, not {participant}'s "
                            "(files swapped or copied between participants?). Nothing was read from it.")
        what = (f"is {st.st_size} bytes, but {integ.get('bytes')} were recorded in {MANIFEST} (truncated or replaced)"
                if digest is None else f"its content does not match the sha256 recorded in {MANIFEST} (damaged, "
                                       "or edited outside memora)")
        raise BankError(f"{db}: {what}. Nothing was read from it. `memora verify {self.directory}` reports every "
                        f"participant; rebuild this one with `memora build {self.directory} --rebuild {participant}`.")

    def check_before_build(self, participant: str) -> None:
        """Before a build reads (and later extends) a participant's database: a sealed one must
        match its record; an interrupted build's one, with a write-ahead log or shadow file to
        replay, is opened in a child process first (a crash there is an error here); a database
        the manifest does not list is refused. Skipped under `--no-verify`."""
        if not verify_default() or not self.manifest.exists():
            return
        data = self.manifest.read()
        db = self.manifest.db_path(participant)
        mark = data.get("writing", {}).get(participant)
        if mark:
            if mark.get("pid") != os.getpid() and pid_alive(mark.get("pid")):
                raise BankError(self.interrupted_message(participant, mark))
            if side_files(db):
                from memora_graph.files import probe

                probe(db, participant)
            return
        entry = data["participants"].get(participant)
        if entry is None:
            if db.exists():
                raise BankError(self.not_listed(participant, data))
            return
        if entry.get("integrity"):
            self.check(participant, data)

    def checked_db_file(self, participant: str) -> Path:
        """A participant's database path, refused (BankError naming it) unless it is a regular
        file of its own, directly inside the bank: not missing, not a folder, a device, a pipe or
        a symbolic link (which could point at a copy outside the bank, or /dev/zero)."""
        db = self.manifest.db_path(participant)
        try:
            st = db.lstat()
        except FileNotFoundError:
            raise BankError(f"{db}: missing. Rebuild it with `memora build {self.directory} --rebuild {participant}`, "
                            f"or `memora forget {self.directory} --participant {participant}`.") from None
        except OSError as exc:
            raise BankError(f"{db}: cannot be read ({exc.strerror or exc})") from None
        kind = file_kind(st)
        if kind != "file":
            raise BankError(f"{db}: is {kind}, not a database file; nothing was read from it. Move it away and "
                            f"rebuild: `memora build {self.directory} --rebuild {participant}`.")
        if db.resolve().parent != self.directory.resolve():
            raise BankError(f"{db}: resolves to {db.resolve()}, outside the bank {self.directory.resolve()}; refused")
        return db

    def checked_sha256(self, participant: str) -> str | None:
        """Run the checks a read-only open runs before Kùzu touches the file (listed, no write
        in progress, no foreign log, size and sha256 as recorded) without opening it, and return
        the recorded sha256 the file matches: what files derived from the database are tied to.
        None under --no-verify or while this process writes it (nothing to vouch for then)."""
        data = self.manifest.read()
        if not verify_default() or WriteMarks.held_here(data, participant):
            return None
        if participant not in data["participants"]:
            raise BankError(self.not_listed(participant, data))
        self.notify(data, skip=participant)
        self.check(participant, data)
        return data["participants"][participant]["integrity"]["sha256"]

    def verify_counts(self, participant: str, store: Store, expected: dict) -> None:
        db = self.manifest.db_path(participant)
        try:
            got = {k: int(v or 0) for k, v in store.run("store_counts", participant=participant).to_dicts()[0].items()}
        except Exception as exc:
            raise BankError(f"{db}: cannot read the database ({exc}); it is damaged. Rebuild it "
                            f"with `memora build {self.directory} --rebuild {participant}`.") from exc
        diff = {k: (expected.get(k), got.get(k)) for k in CHECKED_COUNTS if expected.get(k) != got.get(k)}
        if diff:
            detail = ", ".join(f"{k} manifest={a} database={b}" for k, (a, b) in diff.items())
            raise BankError(
                f"{db}: does not match {MANIFEST} ({detail}). The manifest was edited, or the "
                f"database damaged; `memora verify {self.directory}` reports it, `memora build {self.directory} "
                f"--rebuild {participant}` rebuilds it."
            )

    def recorded_for(self, data: dict, participant: str, size: int, db: Path, st, digest: str | None) -> str | None:
        """The other participant whose integrity record `db` (of `size` bytes, stat `st`, sha256
        `digest` if known) matches: a file swapped or copied between participants."""
        for other, entry in sorted(data["participants"].items()):
            integ = entry.get("integrity") or {}
            if other != participant and integ.get("bytes") == size:
                if (digest or file_sha256(db, st)) == integ.get("sha256"):
                    return other
        return None

    def interrupted_message(self, participant: str, mark: dict) -> str:
        db, op, pid, since = (self.manifest.db_path(participant), mark.get("op", "write"), mark.get("pid"),
                              mark.get("since", "?"))
        pid = pid if pid is not None else mark.get("failed_in")
        if mark.get("pid") is not None and pid_alive(pid):
            return (f"{db}: being written by process {pid} ({op} since {since}); wait for it to finish "
                    "(or stop it), then retry.")
        if op == "build":
            return (f"{db}: its build was interrupted ({since}, process {pid} failed or is gone), so {participant}'s memory is "
                    f"incomplete. Resume it with `memora build {self.directory} --participants {participant}` (or "
                    f"`memora build {self.directory} --rebuild {participant}`).")
        if op == "live":
            return (f"{db}: its live writer ({since}, process {pid}) stopped without closing; what it acknowledged is in "
                    f"its write-ahead log. The next writer replays it (`memora remember {self.directory} --participant "
                    f"{participant} ...`, `memora serve {self.directory} --participant {participant} --writable`), as does "
                    f"`memora verify {self.directory} --accept {participant}`.")
        return (f"{db}: a write to it ({op}, {since}) did not finish (process {pid} failed or is gone). `memora verify "
                f"{self.directory}` reports it; `memora verify {self.directory} --accept {participant}` keeps what that "
                f"write committed, or rebuild: `memora build {self.directory} --rebuild {participant}`.")

    def not_listed(self, participant: str, data: dict) -> str:
        """Why a participant the manifest `data` does not list is refused (its file there or not)."""
        known = ", ".join(sorted(data["participants"])) or "none"
        db = self.manifest.db_path(participant)
        if db.exists():
            return (f"{db}: exists, but {MANIFEST} does not list {participant} (its entry was removed, or the file was "
                    f"copied in), so it is not read. `memora verify {self.directory}` reports it; `memora forget "
                    f"{self.directory} --participant {participant}` deletes it. (The bank has: {known})")
        return f"{self.directory}: participant {participant} is not in this bank (has: {known})"

    def notices(self, data: dict | None = None) -> list[tuple[str, str]]:
        """What a reader should know about the whole bank, as (participant, text), from a
        directory listing (no hashing): interrupted or running writes, staged videos of
        interrupted builds, databases the manifest does not list, listed participants whose
        database is missing."""
        data = data or self.manifest.read()
        out = []
        marks = data.get("writing", {})
        for p, mark in sorted(marks.items()):
            if mark.get("pid") != os.getpid():
                out.append((p, self.interrupted_message(p, mark)))
        staging = self.directory / ".staging"
        if staging.is_dir():
            for d in sorted(x for x in staging.iterdir() if x.is_dir() and PARTICIPANT_ID.match(x.name)):
                n = sum(1 for x in d.iterdir() if x.is_dir() and not x.name.startswith("."))
                if n and d.name not in marks:
                    out.append((d.name, f"{d}: a build of {d.name} was interrupted with {n} video(s) staged; "
                                        f"`memora build {self.directory} --participants {d.name}` resumes it"))
        for f in sorted(self.directory.glob("*.kuzu")):
            m = DB_FILE.match(f.name)
            if m and m.group(1) not in data["participants"] and m.group(1) not in marks:
                out.append((m.group(1), self.not_listed(m.group(1), data)))
        for p in sorted(data["participants"]):
            if p not in marks and not self.manifest.db_path(p).exists():
                out.append((p, f"{self.manifest.db_path(p)}: missing, but {MANIFEST} lists {p}"))
        return out

    def notify(self, data: dict, skip: str | None = None) -> None:
        """Log the bank's notices once per process (the CLI prints them as warnings), except
        those about `skip`, the participant being opened (its own check says it)."""
        for p, line in self.notices(data):
            key = (str(self.directory.resolve()), line)
            if p != skip and key not in NOTICED:
                NOTICED.add(key)
                log.warning(line)

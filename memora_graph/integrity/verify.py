"""`memora verify`: a deep report on a bank, and accepting a database as it is now.

Per participant: is its database listed in the manifest and present, do its size and sha256
match the record of its last write, do its rows per table match (and hold no other
participant's rows), is there a write-ahead log or shadow file next to it, did a write or a
build not finish (staged videos, a write mark), are its staged videos intact. For the bank:
files that are none of these. A database whose hash does not match is only ever opened in a
child process (Kùzu can crash on a damaged file), so verify itself cannot crash.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import polars as pl

from memora_graph.bank import BUILD_LOCK, MANIFEST, VERIFIED, Bank, pid_alive
from memora_graph.bank.derived import sha256_file
from memora_graph.errors import BankError
from memora_graph.form.staging import Staging
from memora_graph.files import RECOVERY, file_kind, file_sha256, keep_log, probe, replay, side_files
from memora_graph.ids import PATTERN, is_participant_id
from memora_graph.integrity.probe import machine_pool
from memora_graph.store import MB, Store, wal_path

_DB = re.compile(rf"\A({PATTERN})\.kuzu(\.wal|\.shadow)?\Z")
KNOWN = {MANIFEST, MANIFEST + ".tmp", ".manifest.lock", BUILD_LOCK, VERIFIED, ".staging", ".cache", ".trash", RECOVERY}
PROBE_TIMEOUT_S = 60


@dataclass
class Report:
    rows: list[dict] = field(default_factory=list)  # one per participant
    bank: list[str] = field(default_factory=list)  # problems of the bank as a whole

    @property
    def ok(self) -> bool:
        return not self.bank and all(r["status"] == "ok" for r in self.rows)

    def frame(self) -> pl.DataFrame:
        return pl.DataFrame(self.rows) if self.rows else pl.DataFrame()


def verify_bank(path: str | Path, participants: list[str] | None = None) -> Report:
    bank = Bank(path)
    data = bank.manifest()
    marks = data.get("writing", {})
    on_disk = {m.group(1) for f in bank.path.iterdir() if (m := _DB.match(f.name))}
    staging_root = bank.path / ".staging"
    staged = {d.name for d in staging_root.iterdir() if d.is_dir()} if staging_root.is_dir() else set()
    everyone = sorted(set(data["participants"]) | on_disk | set(marks) | {p for p in staged if is_participant_id(p)})
    report = Report()
    for p in participants or everyone:
        report.rows.append(_participant(bank, data, p))
    if not participants:
        _caches(bank, bank.derived.get_all(None, data), report.bank)
        for f in sorted(bank.path.iterdir()):
            if f.name not in KNOWN and not _DB.match(f.name) and not f.name.startswith(VERIFIED + "."):
                report.bank.append(f"{f}: not a file of a memora bank (foreign)")
        if staging_root.is_dir():
            for d in sorted(staging_root.iterdir()):
                if not (d.is_dir() and is_participant_id(d.name)):
                    report.bank.append(f"{d}: not a participant's staging folder (foreign; never opened)")
        trash = bank.path / ".trash"
        if trash.is_dir():
            for d in sorted(trash.iterdir()):
                report.bank.append(f"{d}: the previous database of an interrupted rebuild (removed when the rebuild "
                                   f"completes: `memora build {bank.path} --participants {d.name.rsplit('-', 1)[0]}`)")
    return report


def _participant(bank: Bank, data: dict, p: str) -> dict:
    db = bank.db_path(p)
    entry = data["participants"].get(p)
    integ = (entry or {}).get("integrity") or {}
    mark = data.get("writing", {}).get(p)
    sides = side_files(db)
    problems: list[str] = []
    row = {"participant": p, "file": db.name, "listed": entry is not None, "hash": "-", "tables": "-",
           "other_participant_rows": None, "wal": "present" if any(s.suffix == ".wal" for s in sides) else "none",
           "shadow": "present" if any(s.suffix == ".shadow" for s in sides) else "none", "write": "-", "staging": "-"}
    if mark:
        alive = pid_alive(mark.get("pid"))
        row["write"] = f"{'running' if alive else 'interrupted'} {mark.get('op', 'write')} ({mark.get('since', '?')})"
        problems.append(bank.interrupted_message(p, mark))
    try:
        kind = file_kind(db.lstat())
    except FileNotFoundError:
        kind = "missing"
    if entry is None and kind != "missing" and not mark:
        problems.append(f"{db}: not listed in {MANIFEST} (entry removed, or file copied in); readers do not see it")
    if entry is not None and kind == "missing":
        row["hash"] = "missing"
        problems.append(f"{db}: missing, but {MANIFEST} lists {p}")
    elif kind not in ("file", "missing"):
        row["hash"] = kind
        problems.append(f"{db}: is {kind}, not a database file; every reader refuses it (move it away and rebuild: "
                        f"`memora build {bank.path} --rebuild {p}`)")
    if sides and not mark:
        problems.append(f"{', '.join(s.name for s in sides)}: next to a database that was closed cleanly: does not "
                        "belong to it (never replayed; move it away)")
    counts = None
    if kind == "file":
        st = db.stat()
        if not integ:
            row["hash"] = "not recorded"
            if entry is not None and not mark:
                problems.append(f"{db}: no hash recorded (built before integrity records); "
                                f"`memora verify {bank.path} --accept {p}` records it as it is now")
        elif st.st_size != integ.get("bytes"):
            row["hash"] = f"size {st.st_size} != {integ.get('bytes')}"
        elif file_sha256(db, st) != integ.get("sha256"):
            row["hash"] = "differs"
        else:
            row["hash"] = "ok"
        if integ and row["hash"] != "ok" and not mark:
            owner = [q for q, e in data["participants"].items()
                     if q != p and (e.get("integrity") or {}).get("sha256") == file_sha256(db, st)]
            row["hash"] += f" (is {owner[0]}'s database)" if owner else ""
            problems.append(f"{db}: {row['hash']}: damaged, edited or replaced since its last write")
        try:
            if row["hash"] == "ok" and not sides:
                with Store(db, read_only=True) as store:  # the bytes are those recorded: safe to open here
                    counts = {"tables": store.table_counts(p),
                              "counts": store.rows("store_counts", participant=p)[0]}
            elif not integ or mark:  # nothing to vouch for it: opened in a child process only
                counts = probe(db, p, timeout=PROBE_TIMEOUT_S)
                replayed = counts.get("replay") or {}
                if replayed.get("log_bytes"):  # its log replayed (read-only) there: how big, with how much memory
                    row["wal"] = recoverable(replayed)
            else:  # known to differ from its record: Kùzu can crash or spin on it, and its rows are moot
                row["tables"] = "not opened (differs from its record)"
        except BankError as exc:
            row["tables"] = "cannot be opened"
            if any(s.suffix == ".wal" for s in sides):
                row["wal"] = f"{wal_path(db).stat().st_size / 1e6:.1f} MB: cannot be replayed here"
            problems.append(str(exc))
    if counts is not None:
        tables = counts["tables"]
        row["other_participant_rows"] = sum(v["other_participant"] for v in tables.values())
        if row["other_participant_rows"]:
            problems.append(f"{db}: holds {row['other_participant_rows']} row(s) of another participant")
        recorded = integ.get("tables")
        if recorded:
            diff = [f"{t}: manifest {recorded.get(t)} != database {tables.get(t, {}).get('rows')}"
                    for t in sorted(set(recorded) | set(tables)) if recorded.get(t) != tables.get(t, {}).get("rows")]
            row["tables"] = "ok" if not diff else "; ".join(diff)
            if diff:
                problems.append(f"{db}: rows per table differ from {MANIFEST}: {'; '.join(diff)}")
        else:
            row["tables"] = f"{len(tables)} tables (none recorded)"
        expected = (entry or {}).get("counts", {})
        got = {k: int(v or 0) for k, v in counts["counts"].items()}
        off = [f"{k} manifest {expected[k]} != database {got.get(k)}" for k in sorted(expected)
               if k in got and expected[k] != got[k]]
        if off and entry is not None and not mark:
            problems.append(f"{db}: counts differ from {MANIFEST}: {'; '.join(off)}")
    staging = Staging(bank.path / ".staging" / p)
    entries, foreign, half = staging.entries(), staging.foreign(), staging.half_written()
    if entries or foreign or half:
        bad = [(e.name, why) for e in entries if (why := Staging.check(e))]
        row["staging"] = f"{len(entries)} video(s)" + (f", {len(bad)} damaged" if bad else "") + \
            (f", {len(foreign)} foreign file(s)" if foreign else "") + \
            (f", {len(half)} half-written folder(s) of a killed build (the next build removes them)" if half else "")
        if entries and not mark:
            problems.append(f"{staging.root}: a build of {p} was interrupted with {len(entries)} video(s) staged; "
                            f"`memora build {bank.path} --participants {p}` resumes it")
        for name, why in bad:
            problems.append(f"{staging.root / name}: {why} (a build will build it again)")
        for f in foreign:
            problems.append(f"{f}: not a staged video (never opened by a build; remove it)")
    row["tool_stores"] = _tool_stores(bank, data, p, integ, problems)
    row["caches"] = _caches(bank, bank.derived.get_all(p, data), problems)
    row["status"] = "ok" if not problems else "problem"
    row["problems"] = problems
    return row


def recoverable(replayed: dict) -> str:
    """What replaying a log took, in words: "15.5 MB: recoverable: replay needs 473 MB (...)"."""
    pool = replayed.get("pool_bytes") or machine_pool()
    return (f"{replayed['log_bytes'] / 1e6:.1f} MB: recoverable: replay needs {pool / MB:.0f} MB "
            f"(the buffer pool it was replayed with, read-only, in {replayed.get('seconds', 0):.1f} s)")


def _tool_stores(bank: Bank, data: dict, p: str, integ: dict, problems: list[str]) -> str:
    """The stores persisted for one-shot tools (memora_graph/retrieve/persist.py), every file
    hashed against the record of them in the manifest (not against their own meta.json): stale
    ones (from an earlier version of the database) or ones the manifest has no record of are
    expected after a write and never read; a damaged one is reported, by file (never read
    either; written again on the next open)."""
    from memora_graph.retrieve.persist import RECORD, PersistedStores, StaleStores, store_dir

    if not store_dir(bank.path, p).exists():
        return "none (computed on first use)"
    try:
        PersistedStores.open(bank.path, p, integ.get("sha256"), data.get("embed_model"), trust_stamps=False,
                             record=bank.derived.get(p, RECORD, data))
    except StaleStores as why:
        if why.damaged:
            problems.append(f"{why}; never read (the next open reads the database and writes them again)")
            return "damaged"
        if "not recorded" in str(why):
            return "not recorded (never read; written again on the next open)"
        return "stale (written again on the next open)"
    return "ok"


def _caches(bank: Bank, records: dict, problems: list[str]) -> str:
    """The other files derived from a database (baseline caches, kept consolidation folds) or from
    the whole bank (the embedding cache), each hashed against its record in the manifest
    (bank/derived.py). A file that is not as recorded is reported by name (readers never use
    it: they build it again); a recorded file since removed is not a problem."""
    checked = bad = 0
    for name, record in sorted(records.items()):
        files = record.get("files") if isinstance(record, dict) else None
        if name == "tools" or not isinstance(files, dict):
            continue
        for fname, digest in sorted(files.items()):
            path = bank.path / ".cache" / fname
            if "/" in fname or not path.is_file():
                continue
            checked += 1
            if sha256_file(path) != digest:
                bad += 1
                problems.append(f"{path}: not as recorded in {MANIFEST} (edited or damaged); never read (built again "
                                "on next use)")
    return "none" if not checked else (f"{bad} of {checked} damaged" if bad else f"ok ({checked} files)")


def accept(path: str | Path, participant: str) -> dict:
    """Record a listed participant's database as it is now: for a bank built before integrity
    records, or after a write (`memora query --write`, consolidation) that did not finish. Its
    log is first replayed in a child process (a crash there refuses it), then here, and the
    integrity recorded. Not for interrupted builds: `memora build` resumes those."""
    bank = Bank(path)
    data = bank.manifest()
    db = bank.db_path(participant)
    if participant not in data["participants"]:
        raise BankError(bank.not_listed(participant, data))
    mark = data.get("writing", {}).get(participant)
    if mark and pid_alive(mark.get("pid")):
        raise BankError(bank.interrupted_message(participant, mark))
    if mark and mark.get("op") == "build":
        raise BankError(f"{db}: its build was interrupted; resume it with `memora build {bank.path} --participants "
                        f"{participant}` rather than accepting half of it")
    bank.checked_db_file(participant)
    if side_files(db):  # a copy of the log first, then replayed into the file in a child process (its
        keep_log(db)    # buffer pool sized from the log; a crash there is an error here)
        replay(db, participant, timeout=PROBE_TIMEOUT_S)
    else:
        probe(db, participant, timeout=PROBE_TIMEOUT_S)
    bank.mark_writing(participant, "accept")
    with Store(db, read_only=False):  # (a log left now is replayed here) checkpointed into the file on close
        pass
    return bank.record_integrity(participant)

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
from memora_graph.form.intake import FOLDER, has_journal, set_log_aside
from memora_graph.form.intake import entries as journal_entries
from memora_graph.form.staging import Staging
from memora_graph.files import RECOVERY, file_kind, file_sha256, keep_log, probe, replay, side_files
from memora_graph.ids import PATTERN, is_participant_id
from memora_graph.integrity.probe import machine_pool
from memora_graph.store import MB, Store, wal_path

_DB = re.compile(rf"\A({PATTERN})\.kuzu(\.wal|\.shadow)?\Z")
# The kind of each problem verify reports, a stable code for scripts and tests (a row's "kinds",
# one per line of its "problems", in order); the words may change, these do not.
KINDS = {
    "write_running": "a write is in progress (its process is alive)",
    "live_interrupted": "a live writer stopped without closing; what it acknowledged is in its log (recoverable)",
    "build_interrupted": "a build was interrupted; `memora build` resumes it",
    "write_interrupted": "another write did not finish; `--accept` keeps what it committed",
    "not_listed": "a database the manifest does not list",
    "missing": "a listed participant's database is missing",
    "not_a_file": "the database path is a folder, link, device or pipe",
    "foreign_log": "a log or shadow file next to a database closed cleanly",
    "no_hash": "no integrity record (a bank from before them)",
    "hash_differs": "size or sha256 not as recorded, no write in progress",
    "cannot_open": "Kùzu cannot open it (with its log), in a child process",
    "journal": "a live writer's log Kùzu cannot replay; its intake journal re-applies the moments acknowledged since "
               "the last checkpoint (recoverable: the next writer, or --accept)",
    "other_participant_rows": "rows of another participant",
    "tables_differ": "rows per table not as recorded (expected while a write is interrupted)",
    "counts_differ": "record counts not as in the manifest",
    "build_staged": "videos staged by an interrupted build",
    "staged_damaged": "a staged video is damaged",
    "staging_foreign": "a file in the staging folder that is not a staged video",
    "tool_stores_damaged": "a persisted tool store not as recorded",
    "cache_damaged": "a derived cache file not as recorded",
}
# What a database's log is (a row's "log"): "none"; "empty" (a file of 0 bytes: nothing to replay, a
# kill after a checkpoint had written everything and before it removed the file); "replayed" (read
# here, read-only, in a child process: recoverable); "checkpoint" (a checkpoint interrupted after
# its log record: the shadow pages only a read-write open replays, done on a copy here:
# recoverable); "not opened" (the file differs from its record with no write to explain it);
# "cannot be replayed"; "present" (not looked at: the database is not opened).
LOG_STATES = ("none", "empty", "replayed", "checkpoint", "not opened", "cannot be replayed", "present")
KNOWN = {FOLDER, MANIFEST, MANIFEST + ".tmp", ".manifest.lock", BUILD_LOCK, VERIFIED, ".staging", ".cache", ".trash", RECOVERY}
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
    kinds: list[str] = []

    def add(kind: str, text: str) -> None:
        problems.append(text)
        kinds.append(kind)

    wal = wal_path(db)
    row = {"participant": p, "file": db.name, "listed": entry is not None, "hash": "-", "tables": "-",
           "other_participant_rows": None, "wal": "present" if wal in sides else "none",
           "log": "present" if wal in sides else "none",
           "shadow": "present" if any(s.suffix == ".shadow" for s in sides) else "none", "write": "-", "staging": "-"}
    if wal in sides and wal.stat().st_size == 0:
        row["wal"], row["log"] = "empty: nothing to replay (0 bytes)", "empty"
    if mark:
        alive = pid_alive(mark.get("pid"))
        op = mark.get("op", "write")
        row["write"] = f"{'running' if alive else 'interrupted'} {op} ({mark.get('since', '?')})"
        add("write_running" if alive else {"live": "live_interrupted", "build": "build_interrupted"}.get(
            op, "write_interrupted"), bank.interrupted_message(p, mark))
    try:
        kind = file_kind(db.lstat())
    except FileNotFoundError:
        kind = "missing"
    if entry is None and kind != "missing" and not mark:
        add("not_listed", f"{db}: not listed in {MANIFEST} (entry removed, or file copied in); readers do not see it")
    if entry is not None and kind == "missing":
        row["hash"] = "missing"
        add("missing", f"{db}: missing, but {MANIFEST} lists {p}")
    elif kind not in ("file", "missing"):
        row["hash"] = kind
        add("not_a_file", f"{db}: is {kind}, not a database file; every reader refuses it (move it away and rebuild: "
                        f"`memora build {bank.path} --rebuild {p}`)")
    if sides and not mark:
        add("foreign_log", f"{', '.join(s.name for s in sides)}: next to a database that was closed cleanly: does not "
                        "belong to it (never replayed; move it away)")
    counts = None
    if kind == "file":
        st = db.stat()
        if not integ:
            row["hash"] = "not recorded"
            if entry is not None and not mark:
                add("no_hash", f"{db}: no hash recorded (built before integrity records); "
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
            add("hash_differs", f"{db}: {row['hash']}: damaged, edited or replaced since its last write")
        try:
            if row["hash"] == "ok" and not sides:
                with Store(db, read_only=True) as store:  # the bytes are those recorded: safe to open here
                    counts = {"tables": store.table_counts(p),
                              "counts": store.rows("store_counts", participant=p)[0]}
            elif not integ or mark:  # nothing to vouch for it: opened in a child process only
                try:
                    counts = probe(db, p, timeout=PROBE_TIMEOUT_S)
                    replayed = counts.get("replay") or {}
                    if replayed.get("log_bytes"):  # its log replayed (read-only) there: how big, with how much memory
                        row["wal"], row["log"] = recoverable(replayed), "replayed"
                except BankError:
                    # a kill during a checkpoint, after its log record: Kùzu replays the shadow pages in a
                    # read-write open only (read-only refuses). Replayed on a copy: recoverable, or the error.
                    if not _shadow_pages(db):
                        raise
                    counts = _probe_copy(db, p)
                    row["wal"], row["log"] = recoverable(counts["replay"], checkpoint=True), "checkpoint"
            else:  # known to differ from its record: Kùzu can crash or spin on it, and its rows are moot
                row["tables"] = "not opened (differs from its record)"
                row["log"] = "not opened" if sides else row["log"]
        except BankError as exc:
            row["tables"] = "cannot be opened"
            if wal in sides:
                row["wal"], row["log"] = f"{wal.stat().st_size / 1e6:.1f} MB: cannot be replayed here", \
                    "cannot be replayed"
            if mark and mark.get("op") == "live" and not pid_alive(mark.get("pid")) and has_journal(bank.path, p):
                n = len(journal_entries(bank.path, p))
                row["log"] = "cannot be replayed"
                add("journal", f"{exc}; recoverable from the intake journal: the log is set aside (kept in "
                               f"{bank.path / RECOVERY}), the database opens as its last checkpoint left it and the "
                               f"journal re-applies the {n} moment(s) it holds, by key (those the checkpoint has are "
                               f"duplicates: nothing written) (`memora verify "
                               f"{bank.path} --accept {p}`, or the next writer)")
            else:
                add("cannot_open", str(exc))
    if counts is not None:
        tables = counts["tables"]
        row["other_participant_rows"] = sum(v["other_participant"] for v in tables.values())
        if row["other_participant_rows"]:
            add("other_participant_rows", f"{db}: holds {row['other_participant_rows']} row(s) of another participant")
        recorded = integ.get("tables")
        if recorded:
            diff = [f"{t}: manifest {recorded.get(t)} != database {tables.get(t, {}).get('rows')}"
                    for t in sorted(set(recorded) | set(tables)) if recorded.get(t) != tables.get(t, {}).get("rows")]
            row["tables"] = "ok" if not diff else "; ".join(diff)
            if diff:
                add("tables_differ", f"{db}: rows per table differ from {MANIFEST}: {'; '.join(diff)}")
        else:
            row["tables"] = f"{len(tables)} tables (none recorded)"
        expected = (entry or {}).get("counts", {})
        got = {k: int(v or 0) for k, v in counts["counts"].items()}
        off = [f"{k} manifest {expected[k]} != database {got.get(k)}" for k in sorted(expected)
               if k in got and expected[k] != got[k]]
        if off and entry is not None and not mark:
            add("counts_differ", f"{db}: counts differ from {MANIFEST}: {'; '.join(off)}")
    staging = Staging(bank.path / ".staging" / p)
    entries, foreign, half = staging.entries(), staging.foreign(), staging.half_written()
    if entries or foreign or half:
        bad = [(e.name, why) for e in entries if (why := Staging.check(e))]
        row["staging"] = f"{len(entries)} video(s)" + (f", {len(bad)} damaged" if bad else "") + \
            (f", {len(foreign)} foreign file(s)" if foreign else "") + \
            (f", {len(half)} half-written folder(s) of a killed build (the next build removes them)" if half else "")
        if entries and not mark:
            add("build_staged", f"{staging.root}: a build of {p} was interrupted with {len(entries)} video(s) staged; "
                            f"`memora build {bank.path} --participants {p}` resumes it")
        for name, why in bad:
            add("staged_damaged", f"{staging.root / name}: {why} (a build will build it again)")
        for f in foreign:
            add("staging_foreign", f"{f}: not a staged video (never opened by a build; remove it)")
    n = len(problems)
    row["tool_stores"] = _tool_stores(bank, data, p, integ, problems)
    kinds += ["tool_stores_damaged"] * (len(problems) - n)
    n = len(problems)
    row["caches"] = _caches(bank, bank.derived.get_all(p, data), problems)
    kinds += ["cache_damaged"] * (len(problems) - n)
    row["status"] = "ok" if not problems else "problem"
    row["problems"], row["kinds"] = problems, kinds
    return row


def _shadow_pages(db: Path) -> bool:
    """Whether a database has a shadow file with pages in it (a checkpoint was under way)."""
    shadow = db.with_name(db.name + ".shadow")
    return shadow.exists() and shadow.stat().st_size > 0


def _probe_copy(db: Path, p: str) -> dict:
    """Replay a database's log and shadow pages read-write into a copy of them (in a temporary
    folder: the bank is not written), then count the copy's rows, both in child processes; the
    counts as `probe` returns them, with what the replay took. A BankError if either fails (the
    copy's path in it replaced by the database's)."""
    import shutil
    import tempfile

    with tempfile.TemporaryDirectory(prefix="memora-verify-") as tmp:
        copy = Path(tmp) / db.name
        try:
            for f in (db, *side_files(db)):
                shutil.copy2(f, copy.with_name(f.name))
        except OSError as exc:
            raise BankError(f"{db}: an interrupted checkpoint (shadow pages), which read-only cannot replay; no room "
                            f"to replay it on a copy in {tmp} ({exc.strerror or exc})") from None
        try:
            replayed = replay(copy, p, timeout=PROBE_TIMEOUT_S)["replay"]
            counts = probe(copy, p, timeout=PROBE_TIMEOUT_S)
        except BankError as exc:
            raise BankError(str(exc).replace(str(copy), str(db)) + " (replayed read-write on a copy)") from None
    return {**counts, "replay": replayed}


def recoverable(replayed: dict, checkpoint: bool = False) -> str:
    """What replaying a log took, in words: "15.5 MB: recoverable: replay needs 473 MB (...)";
    `checkpoint`: an interrupted checkpoint's log and shadow pages, replayed read-write on a copy."""
    pool = replayed.get("pool_bytes") or machine_pool()
    how = ("read-write on a copy: an interrupted checkpoint, whose shadow pages a read-only open cannot replay"
           if checkpoint else "read-only")
    return (f"{replayed['log_bytes'] / 1e6:.1f} MB: recoverable: replay needs {pool / MB:.0f} MB "
            f"(the buffer pool it was replayed with, {how}, in {replayed.get('seconds', 0):.1f} s)")


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
        try:
            replay(db, participant, timeout=PROBE_TIMEOUT_S)
        except BankError:  # a live writer's log Kùzu refuses: set aside, its intake journal re-applied
            if not (mark and mark.get("op") == "live" and has_journal(bank.path, participant)):
                raise
            from memora_graph.form.live import LiveWriter

            set_log_aside(db)
            with LiveWriter(bank.path, participant):  # opens the last checkpoint, re-applies, closes
                pass
            return bank.record_integrity(participant)
    else:
        probe(db, participant, timeout=PROBE_TIMEOUT_S)
    bank.mark_writing(participant, "accept")
    with Store(db, read_only=False):  # (a log left now is replayed here) checkpointed into the file on close
        pass
    return bank.record_integrity(participant)

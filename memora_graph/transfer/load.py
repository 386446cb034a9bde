"""`memora import`: load an export into a bank as a new participant database.

All or nothing: the database is built next to the bank in a temporary folder (schema, then
every table by bulk COPY in one transaction), checked against the counts the export recorded,
and only then moved into place and recorded in the manifest. A refused or failed import leaves
the bank as it was.
"""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from memora_graph.bank import CHECKED_COUNTS, Bank
from memora_graph.errors import BankError, DataError
from memora_graph.store import INDEX_KINDS, Store, index_names
from memora_graph.transfer.dump import ParticipantDump, read_dump


@dataclass
class ImportResult:
    participant: str
    bank: Path
    db: Path
    counts: dict
    rows: dict[str, int] = field(default_factory=dict)  # table (REL: per FROM/TO pair) -> rows loaded
    indexes: list[str] = field(default_factory=list)
    seconds: float = 0.0


def _refuse_if_held(bank: Bank, dump: ParticipantDump, source: Path) -> None:
    """The checks that need only the bank: the participant is new to it, and its mode and
    embedding model are the export's."""
    p = dump.participant
    db = bank.db_path(p)  # also checks the id (memora_graph/ids.py)
    if bank.exists():
        data = bank.manifest()
        if p in data["participants"]:
            raise BankError(f"{bank.path}: already holds participant {p}; nothing was imported from {source}. "
                            f"Import into another bank directory.")
        for key, what in (("mode", "a '{}' bank"), ("embed_model", "embeddings from {}")):
            if data[key] != dump.bank[key]:
                raise BankError(f"{bank.path}: is {what.format(data[key])}, the export of {p} has "
                                f"{what.format(dump.bank[key])}; nothing was imported. Import into another bank directory.")
    if db.exists():
        raise BankError(f"{db}: exists but is not in {bank.path}'s manifest (an interrupted build?); nothing was "
                        f"imported. Delete it, or import into another bank directory.")


def _check_dump(dump: ParticipantDump, catalog: dict, migrations: dict, source: Path) -> None:
    """The export fits this version's schema and holds one participant's rows only."""
    if dump.migrations != migrations:
        theirs, ours = set(dump.migrations.items()), set(migrations.items())
        raise DataError(f"{source}: made with another schema (export: {', '.join(sorted(f for f, _ in theirs - ours)) or '-'}; "
                        f"this version: {', '.join(sorted(f for f, _ in ours - theirs)) or '-'}); export it again "
                        f"with this version of memora")
    for t in dump.tables:
        info = catalog.get(t.name)
        if info is None or info["kind"] != t.kind:
            raise DataError(f"{source}: table {t.name} ({t.kind}) is not in this version's schema")
        want = info["columns"] if t.kind == "NODE" else [("from", "STRING"), ("to", "STRING"), *info["columns"]]
        if [tuple(c) for c in t.columns] != [tuple(c) for c in want]:
            raise DataError(f"{source}: table {t.name} has columns {t.columns}, this version's schema {want}")
        if t.kind == "REL" and (t.from_table, t.to_table) not in info["pairs"]:
            raise DataError(f"{source}: table {t.name} has no {t.from_table} -> {t.to_table} pair in this schema")
        if t.kind == "NODE" and t.frame.height:
            others = t.frame.filter(t.frame["participant"] != dump.participant)["participant"].unique().to_list()
            if others or t.frame["participant"].null_count():
                raise DataError(f"{source}: table {t.name} holds rows of {', '.join(map(str, others)) or 'no participant'}, "
                                f"not only {dump.participant}'s")
    counts = dump.manifest.get("counts")
    if not isinstance(counts, dict) or any(k not in counts for k in CHECKED_COUNTS):
        raise DataError(f"{source}: damaged memora export: its manifest entry has no record counts")


def _load(store: Store, dump: ParticipantDump, catalog: dict) -> dict[str, int]:
    """Every table in one transaction, nodes first; each in the order it was exported."""
    rows = {}
    with store.transaction():
        for t in dump.nodes():
            rows[t.key] = store.copy(t.name, t.frame)
        for t in dump.rels():
            pair = (t.from_table, t.to_table) if len(catalog[t.name]["pairs"]) > 1 else (None, None)
            rows[t.key] = store.copy(t.name, t.frame, *pair)
    return rows


def import_participant(bank_path: str | Path, source: str | Path) -> ImportResult:
    """Import an export (a JSON file or a Parquet directory from `memora export`) into a bank
    (created if missing) as a new participant. Refuses, writing nothing, when the bank already
    holds the participant, when its mode or embedding model differ, or when the file is not a
    memora export of this schema."""
    t0 = time.perf_counter()
    source = Path(source)
    dump = read_dump(source)
    bank = Bank(bank_path)
    p = dump.participant
    _refuse_if_held(bank, dump, source)
    created_bank = not bank.path.exists()
    work = bank.path / f".import-{p}"
    shutil.rmtree(work, ignore_errors=True)  # what a killed import left
    db = bank.db_path(p)
    moved = False
    try:
        work.mkdir(parents=True)
        store = Store(work / f"{p}.kuzu", read_only=False, bulk=True)
        try:
            store.apply_schema()
            catalog = store.catalog()
            _check_dump(dump, catalog, store.migration_checksums(), source)
            rows = _load(store, dump, catalog)
            counts = {k: int(v or 0) for k, v in store.run("store_counts", participant=p).to_dicts()[0].items()}
            expected = dump.manifest["counts"]
            diff = [f"{k} {expected.get(k)} in the export, {counts[k]} loaded" for k in counts
                    if k in expected and int(expected[k]) != counts[k]]
            if diff:
                raise DataError(f"{source}: damaged memora export: {'; '.join(diff)}")
            had = set(dump.manifest.get("indexes") or [])
            kinds = {k: bool(had & set(index_names(k))) for k in INDEX_KINDS}
            if any(kinds.values()):  # the source could run the 'fts' / 'hnsw' recipes: so can the copy
                store.ensure_indexes(**kinds)
            indexes = sorted(store.indexes())
        finally:
            store.close()
        bank.init(mode=dump.bank["mode"], embed_model=dump.bank["embed_model"],
                  consolidated=bool(dump.manifest.get("consolidated", False)))
        _refuse_if_held(bank, dump, source)  # again: another process may have added it meanwhile
        for f in sorted(work.glob(f"{p}.kuzu*"), key=lambda f: f.name != db.name):  # and any file Kùzu keeps beside it
            os.replace(f, bank.path / f.name)
            moved = True
        extra = {k: dump.manifest[k] for k in ("consolidated", "inferred") if k in dump.manifest}
        bank.record_participant(p, list(dump.manifest.get("videos") or []), counts,
                                annotations=dump.manifest.get("annotations"), extra={**extra, "indexes": indexes})
        bank.record_integrity(p)  # the imported file's hash: every later open checks it
    except BaseException:
        if moved:  # not recorded in the manifest: take it back out
            for f in bank.path.glob(f"{p}.kuzu*"):
                f.unlink(missing_ok=True)
        shutil.rmtree(work, ignore_errors=True)
        if created_bank:
            shutil.rmtree(bank.path, ignore_errors=True)
        raise
    shutil.rmtree(work, ignore_errors=True)
    return ImportResult(p, bank.path, db, counts, rows, indexes, time.perf_counter() - t0)

"""Undoing a failed build: a rebuilt participant's old database set aside and put back, what a
failed build left of new participants (or of a bank it created) removed, the set-aside copies
purged once their rebuild is complete. Used by annotation and video builds alike."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

from memora_graph.bank import Bank
from memora_graph.errors import BankError
from memora_graph.ids import DB_FILE


def set_aside(bank: Bank, participant: str) -> Path:
    """Move a participant's database and staged videos to BANK/.trash/<participant>-<time>/ and
    drop its manifest entry (kept there as entry.json), for a rebuild."""
    trash = bank.path / ".trash" / f"{participant}-{int(time.time() * 1000)}"
    trash.mkdir(parents=True)
    with bank.participant_lock(participant):
        for f in sorted(bank.path.glob(f"{participant}.kuzu*")):
            os.replace(f, trash / f.name)
        staging = bank.path / ".staging" / participant
        if staging.exists():
            os.replace(staging, trash / "staging")
        entry = {}

        def change(data: dict) -> None:
            entry.update(data["participants"].pop(participant, {}))
            mark = data.get("writing", {}).pop(participant, None)
            if mark is not None and not data["writing"]:
                data.pop("writing")

        if bank.exists():
            bank.update_manifest(change)
        (trash / "entry.json").write_text(json.dumps(entry, sort_keys=True))
    return trash


def undo_build(bank: Bank, created: bool, new: set[str], aside: dict[str, Path]) -> None:
    """After a failed build: remove what it left of participants new to the bank, put rebuilt
    participants' old databases back, and remove the bank if this build created it and nothing
    of it remains."""
    for p in sorted(new):
        try:
            bank.forget(p, shared_caches=False)
        except BankError:
            pass
    for p, trash in sorted(aside.items()):
        for f in sorted(bank.path.glob(f"{p}.kuzu*")):
            f.unlink()
        for f in sorted(trash.glob(f"{p}.kuzu*")):
            os.replace(f, bank.path / f.name)
        if (trash / "staging").exists():
            os.replace(trash / "staging", bank.path / ".staging" / p)
        entry = json.loads((trash / "entry.json").read_text() or "{}")
        if entry and bank.exists():
            bank.update_manifest(lambda data, p=p, entry=entry: data["participants"].__setitem__(p, entry))
        shutil.rmtree(trash, ignore_errors=True)
    _drop_empty(bank.path / ".trash")
    if created and bank.path.is_dir():
        try:
            empty = not bank.exists() or not bank.manifest()["participants"]
        except BankError:
            empty = False
        if empty and not any(DB_FILE.match(f.name) for f in bank.path.glob("*.kuzu")):
            shutil.rmtree(bank.path, ignore_errors=True)


def purge_trash(bank: Bank, participants: set[str]) -> None:
    """Remove the previous databases of rebuilds that are now complete."""
    trash = bank.path / ".trash"
    if trash.is_dir():
        for d in sorted(trash.iterdir()):
            if d.name.rsplit("-", 1)[0] in participants:  # PARTICIPANT-MILLISECONDS (an id may hold '-')
                shutil.rmtree(d, ignore_errors=True)
    _drop_empty(trash)


def _drop_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass

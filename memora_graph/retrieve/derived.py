"""Tables a higher layer derives from what a view holds, kept next to the persisted tool stores so
that a new process reads them instead of computing them again: `BANK/.cache/derived-NAME-PXX.json`.

The reader's classes of every distinct step wording (agent/query/wordings.py) are one: a
function of the wording, the lexicon and the code that reads it, computed by the agent layer and
only saved and loaded here (this layer does not know what they mean). A file is trusted as every
other file derived from a bank is (bank/derived.py): only when the bank's manifest records it,
under the `key` it was computed with (the caller's: a hash of its lexicon and code) and with the
sha256 of its bytes. A file of another key (stale), not as recorded, or that does not read is
ignored, with a note in the log, and the caller computes the table and saves it again;
`memora verify` checks the file against its record. Nothing is derived from a view without
persisted stores (a bank never persisted, or whose stores turned out stale or damaged): it
computes as before. Writes are whole-file replacements (written aside, then renamed, then
recorded) and best effort: a read-only bank keeps computing.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

from memora_graph.bank import MANIFEST, Bank
from memora_graph.bank.derived import recorded, sha256_bytes
from memora_graph.errors import BankError

FILENAME = "derived-{name}-{participant}.json"

log = logging.getLogger("memora_graph.integrity")


def _where(view, name: str) -> tuple[Path, Path] | None:
    """(the bank, the file) of `name` for `view`'s participant, or None without persisted stores."""
    stores = getattr(view, "_persisted", None)
    bank = getattr(stores, "bank_path", None)
    if bank is None or not name.isidentifier():
        return None
    return Path(bank), Path(bank) / ".cache" / FILENAME.format(name=name, participant=view.participant)


def record_name(name: str) -> str:
    """The name of the file's record among the participant's derived files (bank/derived.py)."""
    return f"derived-{name}"


def load(view, name: str, key: str):
    """The payload saved as `name` under `key` for `view`'s participant, or None (none saved,
    saved under another key, or not as recorded: then it is ignored and a note names it)."""
    where = _where(view, name)
    if where is None:
        return None
    bank, path = where
    try:
        raw = path.read_bytes()
        record = Bank(bank).derived.get(view.participant, record_name(name))
    except (OSError, BankError):
        return None
    if isinstance(record, dict) and record.get("of") != key:
        log.info(f"{path}: computed by another version of the code or lexicon (stale); computed again")
        return None
    try:
        if not recorded(record, key, {path.name: raw}):
            raise ValueError(f"not as recorded in {MANIFEST}")
        return json.loads(raw)
    except (ValueError, TypeError, RecursionError) as exc:
        log.warning(f"{path}: damaged ({exc}); not used, computed again")
        return None


def save(view, name: str, key: str, payload) -> bool:
    """Save `payload` (JSON) as `name` under `key`, and record it in the manifest; False where it
    could not be written (then it is not recorded, so never read)."""
    where = _where(view, name)
    if where is None:
        return False
    bank, path = where
    body = json.dumps(payload, ensure_ascii=False, separators=(",", ":")).encode()
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_bytes(body)
        os.replace(tmp, path)
        return Bank(bank).derived.put(view.participant, record_name(name),
                                      {"of": key, "files": {path.name: sha256_bytes(body)}})
    except (OSError, BankError) as exc:
        log.info(f"{path}: not saved ({exc}); computed again by the next process")
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        return False

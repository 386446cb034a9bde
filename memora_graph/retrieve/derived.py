"""Tables a higher layer derives from what a view holds, kept next to the persisted tool stores so
that a new process reads them instead of computing them again: `BANK/.cache/derived-PXX/NAME.json`.

The reader's classes of every distinct step wording (agent/query/wordings.py) are one: a
function of the wording, the lexicon and the code that reads it, computed by the agent layer and
only saved and loaded here (this layer does not know what they mean). Each file carries the
`key` it was computed under (the caller's: a hash of its lexicon and code) and the sha256 of its
payload: a file of another key (stale) or whose payload does not match its hash or does not read
(damaged) is ignored, with a note in the log, and the caller computes the table and saves it
again. Nothing is derived from a view without persisted stores (a bank never persisted, or whose
stores turned out stale or damaged): it computes as before. Writes are whole-file replacements
(written aside, then renamed) and best effort: a read-only bank keeps computing.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path

FORMAT = 1
DIRNAME = "derived-{participant}"

log = logging.getLogger("memora_graph.integrity")


def _path(view, name: str) -> Path | None:
    stores = getattr(view, "_persisted", None)
    bank = getattr(stores, "bank_path", None)
    if bank is None or not name.isidentifier():
        return None
    return Path(bank) / ".cache" / DIRNAME.format(participant=view.participant) / f"{name}.json"


def load(view, name: str, key: str):
    """The payload saved as `name` under `key` for `view`'s participant, or None (none saved,
    saved under another key, or damaged: then it is ignored and a warning names it)."""
    path = _path(view, name)
    if path is None:
        return None
    try:
        raw = path.read_bytes()
    except OSError:
        return None
    head, _, body = raw.partition(b"\n")
    try:
        header = json.loads(head)
        if not isinstance(header, dict):
            raise ValueError("no header")
        if header.get("format") != FORMAT or header.get("key") != key:
            log.info(f"{path}: computed by another version of the code or lexicon (stale); computed again")
            return None
        if hashlib.sha256(body).hexdigest() != header.get("sha256"):
            raise ValueError("its payload does not match its sha256")
        return json.loads(body)
    except (ValueError, TypeError, RecursionError) as exc:
        log.warning(f"{path}: damaged ({exc}); not used, computed again")
        return None


def save(view, name: str, key: str, payload) -> bool:
    """Save `payload` (JSON) as `name` under `key`; False where it could not be written."""
    path = _path(view, name)
    if path is None:
        return False
    body = json.dumps(payload, ensure_ascii=False, separators=(",", ":")).encode()
    header = json.dumps({"format": FORMAT, "key": key, "sha256": hashlib.sha256(body).hexdigest()}).encode()
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_bytes(header + b"\n" + body)
        os.replace(tmp, path)
        return True
    except OSError:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        return False

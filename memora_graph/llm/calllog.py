"""The call log: one `CallRecord` per model call (role, model, prompt hash, tokens, latency,
retries, repairs), kept in memory and appended to a JSONL file as calls happen; summaries by role
or by any tag. The build turns the records into ModelCall nodes."""

from __future__ import annotations

import hashlib
import json
import statistics
import threading
from pathlib import Path
from typing import Any, Iterable

from pydantic import BaseModel, Field, ValidationError

from memora_graph.llm.errors import ModelError


def prompt_hash(messages: list[dict[str, Any]]) -> str:
    """sha256 of the canonical JSON of the messages (sorted keys, no whitespace)."""
    canonical = json.dumps(messages, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


class CallRecord(BaseModel):
    """One model call as seen by the caller (transport retries and the repair turn included)."""

    role: str
    backend: str
    model: str | None
    prompt_hash: str
    tokens_in: int | None = None
    tokens_out: int | None = None
    latency_s: float
    retries: int = 0  # requests re-sent after 429 / 5xx / timeout / dropped connection
    repairs: int = 0  # repair turns after an invalid structured reply (0 or 1)
    ok: bool
    error: str | None = None
    started_at: str
    tags: dict[str, str] = Field(default_factory=dict)  # caller context, e.g. {"segment": ...}
    server_s: float | None = None  # time the server reported spending (X-Server-Time), when it does
    cpu_s: float | None = None  # CPU time this call took on its own thread (sync calls): our overhead


class CallLog:
    """Collects call records in memory; with `path`, also appends each one as a JSON line."""

    def __init__(self, path: str | Path | None = None):
        self.path = Path(path) if path is not None else None
        self.records: list[CallRecord] = []
        self._lock = threading.Lock()

    def add(self, record: CallRecord) -> None:
        with self._lock:
            self.records.append(record)
            if self.path is not None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                with self.path.open("a", encoding="utf-8") as fh:
                    fh.write(record.model_dump_json() + "\n")

    def write_jsonl(self, path: str | Path, *, append: bool = True) -> Path:
        """Write (or append) every record collected so far as JSON lines."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with self._lock, path.open("a" if append else "w", encoding="utf-8") as fh:
            for record in self.records:
                fh.write(record.model_dump_json() + "\n")
        return path

    @staticmethod
    def read_jsonl(path: str | Path) -> list[CallRecord]:
        path = Path(path)
        out = []
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if not line.strip():
                continue
            try:
                out.append(CallRecord.model_validate_json(line))
            except ValidationError as exc:
                raise ModelError(f"{path}: line {number} is not a call record: {exc}") from exc
        return out

    def summary(self, by: str | Iterable[str] = "role") -> list[dict[str, Any]]:
        return summarize_calls(self.records, by=by)

    def __len__(self) -> int:
        return len(self.records)


def summarize_calls(records: Iterable[CallRecord], by: str | Iterable[str] = "role") -> list[dict[str, Any]]:
    """Group records by record fields or tag keys (e.g. "role", ("segment", "role")).

    One row per group: calls, errors, tokens in / out (sums over records that report them),
    latency total / mean / median in seconds, retries and repairs. Rows are sorted by key.
    """
    keys = (by,) if isinstance(by, str) else tuple(by)
    groups: dict[tuple, list[CallRecord]] = {}
    for record in records:
        data = record.model_dump()
        key = tuple(data[k] if k in data and k != "tags" else record.tags.get(k) for k in keys)
        groups.setdefault(key, []).append(record)
    rows = []
    for key in sorted(groups, key=lambda k: tuple("" if v is None else str(v) for v in k)):
        group = groups[key]
        latencies = [r.latency_s for r in group]
        tin = [r.tokens_in for r in group if r.tokens_in is not None]
        tout = [r.tokens_out for r in group if r.tokens_out is not None]
        row: dict[str, Any] = dict(zip(keys, key))
        row.update(
            calls=len(group),
            errors=sum(not r.ok for r in group),
            tokens_in=sum(tin) if tin else None,
            tokens_out=sum(tout) if tout else None,
            latency_total_s=round(sum(latencies), 6),
            latency_mean_s=round(statistics.fmean(latencies), 6),
            latency_median_s=round(statistics.median(latencies), 6),
            retries=sum(r.retries for r in group),
            repairs=sum(r.repairs for r in group),
        )
        rows.append(row)
    return rows


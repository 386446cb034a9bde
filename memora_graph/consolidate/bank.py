"""Consolidation of a whole bank (`memora consolidate`): which participants can be consolidated,
and one row per participant of what the processors made, with the failures accounted for."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from memora_graph.bank import Bank
from memora_graph.consolidate.processors import Processors
from memora_graph.consolidate.run import finish_participant
from memora_graph.errors import ConsolidationError, MemoraError, StoreError


@dataclass
class BankConsolidation:
    """One row per participant (status "consolidated", or "unchanged" when every model step
    failed and the previous knowledge was kept), the failures as lines, and the model calls."""

    rows: list[dict] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    calls: list | None = None

    @property
    def ok(self) -> bool:
        return all(r["status"] == "consolidated" for r in self.rows)

    def calls_line(self, bank) -> str | None:
        if self.calls is None:
            return None
        tokens = sum((r.tokens_in or 0) + (r.tokens_out or 0) for r in self.calls)
        return (f"{len(self.calls)} model calls ({sum(not r.ok for r in self.calls)} failed, {tokens} tokens); "
                f"per role: memora stats {bank} --calls role")


def consolidation_targets(bank: Bank, participants: list[str] | None) -> list[str]:
    """The participants to consolidate (None: every one in the bank). Refuses a raw bank and
    participants the bank does not have, naming them."""
    data = bank.manifest()
    if data.get("mode") == "raw":
        raise MemoraError(f"{bank.path}: a raw bank (one record per observation) is not consolidated; "
                          "build an edited bank to consolidate")
    known = sorted(data["participants"])
    pids = known if participants is None else list(participants)
    missing = [p for p in pids if p not in data["participants"]]
    if missing:
        raise MemoraError(f"{bank.path}: no participant {', '.join(missing)} in this bank "
                          f"(has: {', '.join(known) or 'none'})")
    if not pids:
        raise MemoraError(f"{bank.path}: no participants to consolidate")
    return pids


def _check_writable(bank: Bank, participants: list[str]) -> None:
    """Open every participant's database for writing once, so that one another process holds
    fails before any model call or task."""
    for p in participants:
        try:
            bank.open(p, read_only=False).close()
        except StoreError as exc:
            raise MemoraError(f"cannot consolidate {p}: {exc}") from exc


def consolidate_bank(bank: Bank, participants: list[str], processors: Processors, embedder=None,
                     on_participant: Callable[[str], None] | None = None,
                     on_done: Callable[[str], None] | None = None) -> BankConsolidation:
    """Re-run consolidation and enrichment for each participant, each in one transaction.

    Every participant's database is first opened for writing once, so that one another process
    holds fails before any model call. A participant whose every model step failed keeps its
    previous knowledge and gets an "unchanged" row; failed steps are listed in `failed`."""
    _check_writable(bank, participants)
    if embedder is None:
        from memora_graph.embed import get_embedder

        embedder = get_embedder(bank.manifest()["embed_model"])
    out = BankConsolidation()
    for p in participants:
        if on_participant is not None:
            on_participant(p)
        t0 = time.perf_counter()
        try:
            knowledge = finish_participant(bank, p, embedder, processors=processors)
        except ConsolidationError as exc:
            out.failed.append(str(exc))
            out.rows.append({"participant": p, "processor": processors.name, "routines": None, "preferences": None,
                             "dropped_ids": None, "dropped_records": None, "model_calls": None, "failed_steps": None,
                             "status": "unchanged (every model step failed)",
                             "seconds": round(time.perf_counter() - t0, 1)})
        else:
            out.rows.append({"participant": p, "processor": processors.name, "routines": len(knowledge.routines),
                             "preferences": len(knowledge.preferences), "dropped_ids": knowledge.dropped_ids,
                             "dropped_records": knowledge.dropped_records, "model_calls": len(knowledge.calls),
                             "failed_steps": len(knowledge.failed_steps), "status": "consolidated",
                             "seconds": round(time.perf_counter() - t0, 1)})
            out.failed += [f"{p} {s.step}: {s.error}" for s in knowledge.failed_steps]
        if on_done is not None:
            on_done(p)
    if processors.call_log is not None:
        out.calls = list(processors.call_log.records)
    return out


def consolidate_bank_on_ray(executor, bank: Bank, participants: list[str], processor: str, processors: Processors,
                            llm_options: dict | None, on_done: Callable[[str], None] | None = None,
                            on_step: Callable[[str, str], None] | None = None,
                            on_notice: Callable[[str], None] | None = None) -> BankConsolidation:
    """`consolidate_bank` with one Ray task per participant (memora_graph/consolidate/ray.py):
    the same rows and failure lines; the tasks' model calls join `processors.call_log`.
    `processor` is the registered name the tasks build their own processors from."""
    from memora_graph.consolidate.ray import consolidate_on_ray

    _check_writable(bank, participants)
    out = BankConsolidation()
    for row, lines, calls in consolidate_on_ray(executor, bank, participants, processor, llm_options,
                                                on_participant=on_done, on_step=on_step, on_notice=on_notice):
        out.rows.append(row)
        out.failed += lines
        if processors.call_log is not None:
            processors.call_log.records.extend(calls)
    if processors.call_log is not None:
        out.calls = list(processors.call_log.records)
    return out

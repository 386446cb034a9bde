"""Bank statistics: counts per store, entity compression and the editor's decision mix."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from memora_graph.bank import Bank


def decision_shares(decisions: dict) -> dict[str, float]:
    """Each editor decision's share of all decisions, in percent (one decimal)."""
    total = sum(decisions.values()) or 1
    return {op: round(100.0 * decisions.get(op, 0) / total, 1) for op in ("NOOP", "UPDATE", "ADD", "DELETE")}


def bank_stats(bank_path: str | Path, participants: list[str] | None = None) -> pl.DataFrame:
    bank = Bank(bank_path)
    rows = []
    for p in participants or bank.participants():
        with bank.open(p) as store:
            counts = {k: int(v or 0) for k, v in store.run("store_counts", participant=p).to_dicts()[0].items()}
            decisions = {r["op"]: int(r["n"]) for r in store.rows("decision_mix", participant=p)}
        shares = decision_shares(decisions)
        entities = counts["entities"]
        rows.append({
            "participant": p, **counts,
            "compression": round(counts["state_events"] / entities, 1) if entities else None,
            **{f"{op}%": shares[op] for op in ("NOOP", "UPDATE", "ADD", "DELETE")},
            "decisions": sum(decisions.values()),
        })
    return pl.DataFrame(rows)


def memory_formation(bank_path: str | Path, participant: str) -> dict:
    """The editor's effect on one participant's Entity Memory, segment by segment (videos in id
    order, turns in order): cumulative records without editing (one per observation) and with
    the editor (ADD minus DELETE: the live entities), plus the decision counts. The data of the
    report's compression curve and decision-mix figures."""
    with Bank(bank_path).open(participant) as store:
        rows = store.rows("compression_curve", participant=participant)
        decisions = {r["op"]: int(r["n"]) for r in store.rows("decision_mix", participant=participant)}
    per: dict[tuple[str, int], list[int]] = {}
    for r in rows:  # one row per segment and side (observations; decisions), merged here
        acc = per.setdefault((r["video"], int(r["turn"])), [0, 0])
        acc[0] += int(r["observations"])
        acc[1] += int(r["adds"]) - int(r["deletes"])
    raw = edited = 0
    without, with_editor = [], []
    for key in sorted(per):  # videos in id order, turns in order (sorted here, not by Kùzu)
        raw += per[key][0]
        edited += per[key][1]
        without.append(raw)
        with_editor.append(edited)
    return {"participant": participant, "segments": len(per), "without_editor": without, "with_editor": with_editor,
            "compression": round(raw / edited, 2) if edited else None, "decisions": decisions}


CALL_VIEWS = {"role": "model_calls_by_role", "segment": "model_calls_by_segment", "failed": "model_calls_failed"}


def call_stats(bank_path: str | Path, participants: list[str] | None = None, by: str = "role") -> pl.DataFrame:
    """Model-call cost and latency (video builds, LLM consolidation), per role (and model), per segment, or the
    failed calls. Banks built without models (or before model calls were logged) give no rows."""
    if by not in CALL_VIEWS:
        raise ValueError(f"by must be one of {', '.join(CALL_VIEWS)}")
    bank = Bank(bank_path)
    frames = []
    for p in participants or bank.participants():
        with bank.open(p) as store:
            if "ModelCall" not in store.tables():
                continue
            df = store.run(CALL_VIEWS[by], participant=p)
        if not df.is_empty():
            frames.append(df.select(pl.lit(p).alias("participant"), *df.columns))
    return pl.concat(frames, how="vertical_relaxed") if frames else pl.DataFrame()

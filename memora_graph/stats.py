"""Bank statistics: counts per store, entity compression and the editor's decision mix."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from memora_graph.bank import Bank
from memora_graph.text import counted


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
        rows = store.rows("_compression_curve_all", participant=participant)
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


CALL_VIEWS = {"role": "model_calls_by_role", "segment": "_model_calls_by_segment_all", "failed": "_model_calls_failed_all"}


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


# -- what a build reports (`memora build`) ------------------------------------------------------
def build_summary(result, bank: str | Path, *, episodic: bool = False, mode: str = "edited",
                  fts: bool = False) -> tuple[pl.DataFrame, list[str]]:
    """One row per participant of an annotation build (`pipeline.BankBuild`), and the lines
    that say where the time went."""
    rows = []
    for r in result.participants:
        shares = decision_shares(r.decisions)
        inferred = result.inferred.get(r.participant, {})
        rows.append({
            "participant": r.participant, "videos": r.counts.get("videos"), "built": r.videos_built,
            "segments": r.counts.get("segments"), "entities": r.counts.get("entities"),
            "state_events": r.counts.get("state_events"), "places": r.counts.get("places"),
            "NOOP%": shares["NOOP"], "UPDATE%": shares["UPDATE"], "ADD%": shares["ADD"], "DELETE%": shares["DELETE"],
            "compression": round(r.compression, 1), "routines": inferred.get("routines"),
            "preferences": inferred.get("preferences"), "seconds": round(r.timings.total, 1),
        })
    across = f" (seconds summed over {result.jobs} worker processes)" if result.jobs > 1 else ""
    lines = [f"bank {bank}: {counted(len(rows), 'participant')}, {counted(result.segments, 'new segment')} in {result.wall_seconds:.1f} s: "
             f"embedding {result.embedding_seconds:.1f} s, model load {result.model_seconds:.1f} s, graph work "
             f"{result.graph_seconds:.1f} s{across}; `memora perf build` splits it",
             "inferred knowledge: none (a raw build keeps one record per observation)" if mode == "raw" else
             "inferred knowledge: none (MEMORA-Episodic)" if episodic else
             f"inferred knowledge (consolidation + enrichment): {result.finish.get('consolidation', 0.0):.1f} s"]
    if fts:
        lines.append(f"full-text indexes: {result.finish.get('indexes', 0.0):.1f} s")
    return pl.DataFrame(rows), lines


def video_build_summary(res, bank: str | Path) -> tuple[pl.DataFrame, list[str], list[str]]:
    """One row per video of a video build (`pipeline.VideoBuild`), the summary lines, and
    warnings (turns not written because the model's reply stayed invalid)."""
    rows = [{"video": v["video"], "turns": v.get("turns", 0), "segments": v.get("segments", 0),
             "failed_turns": len(v.get("perception_failed", [])) + len(v.get("editor_failed", [])),
             "seconds": v.get("seconds", 0.0), "status": "already built" if v.get("skipped") else "built"}
            for v in res.videos]
    c, shares = res.counts, decision_shares(res.decisions)
    tokens = sum((r.tokens_in or 0) + (r.tokens_out or 0) for r in res.calls)
    lines = [f"bank {bank}, {res.participant}: {c.get('segments')} segments, {c.get('entities')} entities, "
             f"{c.get('state_events')} state events, {c.get('places')} places; editor NOOP {shares['NOOP']}% "
             f"UPDATE {shares['UPDATE']}% ADD {shares['ADD']}% DELETE {shares['DELETE']}%",
             f"{len(res.calls)} model calls ({sum(not r.ok for r in res.calls)} failed, {tokens} tokens) in "
             f"{res.wall_seconds:.1f} s: waiting for the model {res.model_seconds:.1f} s, decoding "
             f"{res.decode_seconds:.1f} s, graph work {res.graph_seconds:.1f} s, consolidation {res.inferred_seconds:.1f} s"]
    failed = sum(r["failed_turns"] for r in rows)
    warnings = [f"{failed} turn(s) were not written because the model's reply stayed invalid; "
                f"see `memora stats {bank} --calls failed`"] if failed else []
    return pl.DataFrame(rows), lines, warnings

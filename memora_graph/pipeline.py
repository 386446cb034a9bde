"""Build a memory bank from EPIC annotations: the library call behind `memora build`."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from memora_graph.bank import Bank
from memora_graph.embed import get_embedder
from memora_graph.errors import DataError
from memora_graph.form.build import ParticipantBuild, Timings, build_participant
from memora_graph.perceive.annotations import load_annotations, load_class_tables, load_video_info


@dataclass
class BankBuild:
    participants: list[ParticipantBuild] = field(default_factory=list)
    timings: Timings = field(default_factory=Timings)
    load_seconds: float = 0.0
    model_seconds: float = 0.0
    wall_seconds: float = 0.0

    @property
    def segments(self) -> int:
        return sum(p.segments for p in self.participants)


def build_bank(
    bank_path: str | Path,
    participants: list[str] | None = None,
    annotations: str | Path | None = None,
    mode: str = "edited",
    embed_model: str | None = None,
    on_plan: Callable[[dict[str, list[str]]], None] | None = None,
    on_video: Callable[[str, str, int], None] | None = None,
    stop_after: int | None = None,
) -> BankBuild:
    """Build (or resume) a bank. `participants=None` means every participant in the annotations."""
    t_start = time.perf_counter()
    out = BankBuild()
    t0 = time.perf_counter()
    df = load_annotations(annotations, participants=participants)
    meta = Path(annotations).parent if annotations else None
    from memora_graph.paths import epic_dir

    meta = meta or epic_dir()
    classes = load_class_tables(meta)
    durations = dict(load_video_info(meta).select("video_id", "duration").iter_rows())
    found = sorted(df["participant_id"].unique().to_list())
    if participants:
        missing = sorted(set(participants) - set(found))
        if missing:
            raise DataError(f"{annotations or 'bundled annotations'}: no actions for participant(s) {', '.join(missing)}")
    out.load_seconds = time.perf_counter() - t0
    if on_plan:
        on_plan({p: sorted(df.filter(df["participant_id"] == p)["video_id"].unique().to_list()) for p in found})
    t0 = time.perf_counter()
    embedder = get_embedder(embed_model)
    out.model_seconds = time.perf_counter() - t0
    bank = Bank(bank_path)
    bank.init(mode=mode, embed_model=embedder.name, consolidated=False)
    for p in found:
        res = build_participant(
            bank, p, df, durations, classes, embedder, mode=mode,
            on_video=(lambda v, n, p=p: on_video(p, v, n)) if on_video else None, stop_after=stop_after,
        )
        out.participants.append(res)
        out.timings.add(res.timings)
    out.wall_seconds = time.perf_counter() - t_start
    return out

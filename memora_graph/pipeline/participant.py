"""One participant's build and finish, the step every annotation build runs: in this process,
in a worker process (workers.py) or in a Ray task (ray.py)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from memora_graph.bank import Bank
from memora_graph.consolidate import finish_participant
from memora_graph.embed import ThreadGovernor, adaptive_threads
from memora_graph.form.build import ParticipantBuild, build_participant


@dataclass
class BuiltParticipant:
    """One participant's build and finish, as a worker process returns it."""

    build: ParticipantBuild
    setup_seconds: float
    finish: dict[str, float]
    inferred: dict
    inferred_seconds: float
    embedding_seconds: float
    texts_encoded: int
    threads: dict[int, int] = field(default_factory=dict)  # torch threads -> encode calls
    model_seconds: float = 0.0


def build_one(bank: Bank, p: str, actions, durations: dict, classes, embedder, governor: ThreadGovernor, *, mode: str,
               stop_after: int | None, episodic: bool, fts: bool, on_video) -> BuiltParticipant:
    emb0, enc0, calls0 = getattr(embedder, "seconds", 0.0), getattr(embedder, "encoded", 0), dict(governor.calls)
    t0 = time.perf_counter()
    with adaptive_threads(embedder, governor):
        res = build_participant(bank, p, actions, durations, classes, embedder, mode=mode, on_video=on_video,
                                stop_after=stop_after)
    setup = max(time.perf_counter() - t0 - res.timings.total, 0.0)
    t0 = time.perf_counter()
    spent: dict[str, float] = {}
    knowledge = finish_participant(bank, p, embedder, episodic=episodic or mode == "raw", fts=fts, timings=spent)
    inferred = knowledge.counts() if knowledge else {"routines": 0, "preferences": 0}
    res.counts.update({k: inferred[k] for k in ("routines", "preferences")})
    return BuiltParticipant(res, setup, spent, inferred, time.perf_counter() - t0, getattr(embedder, "seconds", 0.0) - emb0,
                  getattr(embedder, "encoded", 0) - enc0,
                  {k: n - calls0.get(k, 0) for k, n in governor.calls.items() if n > calls0.get(k, 0)})

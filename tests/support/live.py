"""Narrated moments for the live-memory tests (a kitchen day, repeated)."""

from __future__ import annotations

from memora_graph.form.live import Moment

KITCHEN = ["open the fridge", "take the milk from the fridge", "pour milk into the cup", "put the milk in the fridge",
           "close the fridge", "wash the cup in the sink", "put the cup on the drying rack", "take a knife from the drawer",
           "cut the bread with the knife", "put the knife in the sink"]


def moments(n: int, video: str = "home-1", offset: float = 0.0) -> list[Moment]:
    return [Moment(video, offset + 4.0 * i, offset + 4.0 * i + 3.0, KITCHEN[i % len(KITCHEN)]) for i in range(n)]

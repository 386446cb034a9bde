"""The stated range of every time that enters a memory: seconds from the start of a video, finite,
at least 0 and at most MAX_VIDEO_SECONDS (24 h; EPIC's longest video lasts 1.5 h, Ego4D's a few
hours). A time outside it (1e308, NaN, infinity, a negative number) is refused with the field
named, wherever it comes from: `remember` (CLI and MCP), a narrations file, an EPIC annotations
file, a video's container."""

from __future__ import annotations

import math

from memora_graph.records import MAX_VIDEO_SECONDS  # the segment records' own bound (records.py)

__all__ = ["MAX_VIDEO_SECONDS", "seconds_problem"]


def seconds_problem(value: object) -> str | None:
    """Why `value` is not a time in seconds within the stated range, or None if it is."""
    try:
        t = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError, OverflowError):
        return "expected seconds from the start of the video (a number)"
    if math.isnan(t) or math.isinf(t):
        return "expected seconds from the start of the video (a finite number, not NaN or infinity)"
    if not 0 <= t <= MAX_VIDEO_SECONDS:
        return f"expected seconds from the start of the video, from 0 to {MAX_VIDEO_SECONDS:.0f} (24 h)"
    return None

"""Building a memory bank: from EPIC annotations (annotations.py, its worker processes in
workers.py, one participant's build in participant.py) or from video files (video.py); undoing
a failed build (rollback.py). The public names are re-exported here."""

from memora_graph.pipeline.annotations import (
    BYTES_PER_SEGMENT,
    NEW_DATABASE_BYTES,
    PEAK_FACTOR,
    BankBuild,
    build_bank,
    changed_annotations,
    check_space,
    rebuild_targets,
    space_needed,
)
from memora_graph.pipeline.video import VideoBuild, build_from_video
from memora_graph.pipeline.workers import auto_jobs

__all__ = [
    "BYTES_PER_SEGMENT",
    "NEW_DATABASE_BYTES",
    "PEAK_FACTOR",
    "BankBuild",
    "VideoBuild",
    "auto_jobs",
    "build_bank",
    "build_from_video",
    "changed_annotations",
    "check_space",
    "rebuild_targets",
    "space_needed",
]

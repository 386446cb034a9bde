"""Detectors of how tasks are done, one module per pattern family. Each reads the participant's
tasks (`consolidate.tasks`), applies its documented rule and thresholds, and returns
`TaskPattern` records with a plain statement, counts, exceptions and evidence segments.

| family | module | rule (thresholds in the module) |
|---|---|---|
| canonical | `canonical` | a recurring task's stages and the steps most of its occurrences share, with variants |
| order | `order` | two actions on one object in the same order in most tasks where both occur |
| staging | `staging` | an object put down at a place and picked up again within a task |
| batch | `batch` | things fetched or carried one at a time, or gathered first as a set |
| repetition | `repetition` | two actions on one object alternating, or one action repeated in passes |
| setup | `setup` | what is done before a recurring task's main step |
| carrier | `carrier` | the tool or container that carries a transfer (pour, scoop, fill) |
| closure | `closure` | what is opened (cupboard, drawer, jar, bag) closed again within the task, or left open |
"""

from __future__ import annotations

from memora_graph.consolidate.patterns import batch, canonical, carrier, closure, order, repetition, setup, staging
from memora_graph.consolidate.task_records import Task, TaskPattern

DETECTORS = {"canonical": canonical.detect, "order": order.detect, "staging": staging.detect, "batch": batch.detect,
             "repetition": repetition.detect, "setup": setup.detect, "carrier": carrier.detect, "closure": closure.detect}


def detect_all(tasks: list[Task]) -> list[TaskPattern]:
    out: list[TaskPattern] = []
    for name, fn in DETECTORS.items():
        out += fn(tasks)
    return out

"""Short handles in prompts ("S3", "F12", "E007") and object names, mapped back to what they stand
for: segment ids, findings, evidence items, entity ids. A reference that is no handle of the
prompt is passed on unchanged, for the collector to drop."""

from __future__ import annotations

import re
from collections import Counter, defaultdict
from collections.abc import Iterable
from typing import Any

from memora_graph.consolidate.memory import MemoryStep, display
from memora_graph.text import uniq


_HANDLE = re.compile(r"^\[?\s*([A-Za-z]?)\s*0*(\d+)\s*\]?$")


class Handles:
    """The short ids of one prompt ("S3", "F12", "E007") and what each stands for."""

    def __init__(self, prefix: str, width: int = 0):
        self.prefix = prefix
        self.width = width
        self._items: dict[int, Any] = {}

    def add(self, value: Any) -> str:
        n = len(self._items) + 1
        self._items[n] = value
        return f"{self.prefix}{n:0{self.width}d}"

    def get(self, ref: str) -> Any:
        m = _HANDLE.match(ref.strip())
        if not m or (m.group(1) and m.group(1).upper() != self.prefix):
            return None
        return self._items.get(int(m.group(2)))

    def __len__(self) -> int:
        return len(self._items)


class EntityNames:
    """Object names -> entity ids, for the USES / ABOUT links of model records. Names are not ids:
    a name that matches no object of the memory links nothing."""

    def __init__(self, steps: Iterable[MemoryStep]):
        counts: dict[str, Counter[str]] = defaultdict(Counter)
        for s in steps:
            for o in s.objects:
                counts[o.kind][o.entity] += 1
        self._by: dict[str, str] = {}
        for kind, c in counts.items():
            entity = c.most_common(1)[0][0]
            self._by.setdefault(kind.lower(), entity)
            self._by.setdefault(display(kind).lower(), entity)

    def entities(self, names: Iterable[str]) -> list[str]:
        out = []
        for name in names:
            key = " ".join(str(name).lower().replace("_", " ").split())
            entity = self._by.get(key) or (self._by.get(key.split()[-1]) if key else None)
            if entity and entity not in out:
                out.append(entity)
        return out


def segment_refs(refs: Iterable[str], handles: Handles) -> list[str]:
    """Segment handles -> segment ids; anything else (a real id, or an invented one) unchanged."""
    out = []
    for r in refs:
        v = handles.get(r)
        out.append(v if v is not None else r)
    return uniq(out)


def resolve_refs(refs: list[str], handles: Handles, kind: type) -> tuple[list, list[str]]:
    """Split cited references into the prompt items of `kind` they name (each once, in citation
    order) and the rest, which are passed on as they are: the collector drops an id that is not
    in the bank."""
    found: dict[int, Any] = {}
    raw = []
    for ref in refs:
        item = handles.get(ref)
        if isinstance(item, kind):
            found.setdefault(id(item), item)
        else:
            raw.append(ref)
    return list(found.values()), raw

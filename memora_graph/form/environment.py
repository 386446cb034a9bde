"""Environment memory: places merged by stable location id, each keeping its update history.

The history is the IN_PLACE edges (segment -> place, op ADD or UPDATE, zones seen then);
the Place record holds the union of zones and features and first/last sightings.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from memora_graph.perceive.vocab import PLACE_NAMES
from memora_graph.records import LayeredSegment


@dataclass
class PlaceState:
    id: str
    participant: str
    location_id: str
    name: str
    zones: list[str] = field(default_factory=list)
    features: list[str] = field(default_factory=list)
    first_seen: float = 0.0
    first_video: str = ""
    last_seen: float = 0.0
    last_video: str = ""
    turn_count: int = 0

    def text(self) -> str:
        return f"{self.name}: {', '.join(self.zones)}" if self.zones else self.name


def place_id(participant: str, location_id: str) -> str:
    return f"{participant}:{location_id}"


class PlaceMemory:
    def __init__(self, participant: str, places: list[PlaceState] | None = None):
        self.participant = participant
        self.places: dict[str, PlaceState] = {p.location_id: p for p in places or []}

    def merge(self, seg: LayeredSegment) -> tuple[list[dict], list[dict]]:
        """Returns (IN_PLACE rows, SPATIAL rows)."""
        env = seg.environment
        locations = list(dict.fromkeys([env.location_id, *env.places, *(o.location for o in seg.objects)]))
        zones_at: dict[str, list[str]] = {}
        for name, zone in env.zones.items():
            zones_at.setdefault(zone.position, []).append(name)
        in_place = []
        for loc in locations:
            zones = sorted(zones_at.get(loc, []))
            p = self.places.get(loc)
            if p is None:
                p = PlaceState(id=place_id(self.participant, loc), participant=self.participant, location_id=loc,
                               name=PLACE_NAMES.get(loc, loc.replace("_", " ")), first_seen=seg.t_start,
                               first_video=seg.video_id)
                self.places[loc] = p
                op = "ADD"
            else:
                op = "UPDATE"
            p.zones = sorted(set(p.zones) | set(zones))
            p.features = sorted(set(p.features) | set(zones))
            p.last_seen, p.last_video = seg.t_end, seg.video_id
            p.turn_count += 1
            in_place.append({"from": seg.segment_id, "to": p.id, "op": op,
                             "is_primary": loc == env.location_id, "zones": zones})
        fixture_place = {o.object_id: o.location for o in seg.objects if o.is_fixture}
        spatial = []
        for r in env.spatial_relations:
            a, b = fixture_place.get(r.subject), fixture_place.get(r.object)
            if a and b and a != b:
                spatial.append({"from": place_id(self.participant, a), "to": place_id(self.participant, b),
                                "relation": r.relation, "video": seg.video_id, "turn": seg.turn_id})
        return in_place, spatial

"""The segment encoder phi for the CPU default: narrated actions -> layered 10 s records.

A VLM would look at the clip; here the EPIC narrations of the actions that start inside the
turn are the observation. Places come from location-like nouns (or the verb's usual place,
or the place carried from the previous turn), states from verbs, spatial relations from the
prepositions of the narration. What this path cannot know (colours not narrated, objects in
view but untouched) stays empty rather than invented.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from memora_graph.perceive.annotations import ClassTables, noun_phrase
from memora_graph.perceive.vocab import (
    COLORS, DEFAULT_PLACE, DEFAULT_STATE, HOLDING_VERBS, KEPT_STATE, MATERIALS, NON_OBJECTS, PLACE_NAMES,
    PLACE_NOUNS, PREPOSITIONS, RELEASING_VERBS, SIZES, SOURCE_WORDS, VERB_PLACE, VERB_STATE,
)
from memora_graph.records import (
    ActionStep, ActivityLayer, EnvironmentLayer, LayeredSegment, ObjectObservation,
    SpatialRelation, VisualProperties, Zone,
)

TURN_SECONDS = 10.0
SUMMARY_LIMIT = 300  # characters of working summary carried to the next turn
HELD_CARRY_TURNS = 2  # an object taken and never put down is assumed in hand this long
_PREP_RE = [(re.compile(rf"\b{re.escape(p)}\b"), rel) for p, rel in PREPOSITIONS]
_NAMED_AFTER = re.compile(r"\b(?:" + "|".join(re.escape(w) for w, _ in sorted(
    [(p, 0) for p, _ in PREPOSITIONS] + [(w, 0) for w in SOURCE_WORDS], key=lambda x: -len(x[0]))) + r")\b")


def slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_") or "object"


def split_noun(surface: str) -> tuple[VisualProperties, list[str]]:
    """'spoon:wooden' -> (material=wooden, []); 'knife:bread' -> ({}, ['bread'])."""
    props: dict[str, str] = {}
    other: list[str] = []
    for part in surface.replace("_", " ").split(":")[1:]:
        for word in part.split():
            if word in COLORS and "color" not in props:
                props["color"] = word
            elif word in MATERIALS and "material" not in props:
                props["material"] = "wooden" if word == "wood" else word
            elif word in SIZES and "size" not in props:
                props["size"] = word
            else:
                other.append(word)
    return VisualProperties(**props), other


@dataclass
class _Context:
    """What perception carries between turns of one video (c_{t-1})."""

    place: str = DEFAULT_PLACE
    held: dict[str, tuple[ObjectObservation, int]] = field(default_factory=dict)  # id -> (obs, turn taken)
    recent: list[str] = field(default_factory=list)

    def summary(self, participant: str) -> str:
        parts = []
        if self.recent:
            parts.append("Recently: " + " | ".join(self.recent[-3:]))
        parts.append(f"{participant} is at the {PLACE_NAMES.get(self.place, self.place)}")
        if self.held:
            parts.append("holding " + ", ".join(o.name for o, _ in self.held.values()))
        text = ". ".join(parts)
        return text if len(text) <= SUMMARY_LIMIT else "..." + text[-(SUMMARY_LIMIT - 3):]


def _relation(narration: str, surfaces: list[str]) -> tuple[str, int] | None:
    """The first preposition of the narration and the index of the noun that follows it."""
    text = narration.lower()
    best = None
    for pattern, rel in _PREP_RE:
        m = pattern.search(text)
        if m and (best is None or m.start() < best[0]):
            best = (m.start(), m.end(), rel)
    if best is None:
        return None
    # the noun named first after it, as a whole word ("cup" is not found inside "cupboard")
    found = [(pos, i) for i, surface in enumerate(surfaces) if (pos := _word_at(text, surface, best[1])) is not None]
    return (best[2], min(found)[1]) if found else None


def _word_at(text: str, surface: str, start: int) -> int | None:
    """Where the head word of a noun (`surface`, EPIC style) is first named in `text` from `start`."""
    head = surface.split(":")[0].replace("_", " ")
    m = re.compile(rf"\b{re.escape(head)}\b").search(text, start)
    return m.start() if m else None


def _named_as_place(narration: str, surfaces: list[str]) -> set[int]:
    """The nouns (by index, never the first: the action's object) named only after a preposition or
    a source word ("in the cupboard", "from the drawer"): where something goes or comes from,
    whose own state the action does not change."""
    text = narration.lower()
    first = _word_at(text, surfaces[0], 0) if surfaces else None
    if first is None:
        return set()
    words = [m for m in _NAMED_AFTER.finditer(text) if m.start() > first]
    out = set()
    for i, surface in enumerate(surfaces[1:], start=1):
        pos = _word_at(text, surface, first + 1)
        if pos is not None and any(m.end() <= pos for m in words):  # a preposition between the object and it
            out.add(i)
    return out


def object_name(surface: str, key: str, adjectives: list[str], extra: list[str]) -> str:
    """An object's name in the person's words: its attributes, the words EPIC adds to its class
    ('washing up' of 'liquid:washing:up') and the class's noun phrase; where those repeat a word
    ('breast:chicken' of class chicken: "chicken chicken"), the noun as said ("chicken breast")."""
    words = " ".join(adjectives + extra + [noun_phrase(key)]).split()
    if len(set(words)) == len(words):
        return " ".join(words)
    parts = [p for p in surface.replace("_", " ").split(":") if p]
    said = [w for p in parts[1:] for w in p.split() if w not in adjectives] + parts[0].split()
    return " ".join(dict.fromkeys(adjectives + said))


def _observe_action(action: dict, t0: float, ctx: _Context, classes: ClassTables) -> tuple[list[ObjectObservation], str, list[SpatialRelation]]:
    verb = action["verb_key"]
    pairs = [(s, c) for s, c in zip(action["all_nouns"], action["all_noun_classes"])
             if classes.nouns.get(c, s) not in NON_OBJECTS]
    keys = [classes.nouns.get(c, s) for s, c in pairs]
    rel = _relation(action["narration"], [s for s, _ in pairs])
    target = rel[1] if rel else None
    kept = _named_as_place(action["narration"], [s for s, _ in pairs])
    place_idx = [i for i, k in enumerate(keys) if k in PLACE_NOUNS]
    if place_idx:
        place = PLACE_NOUNS[keys[place_idx[-1] if target in place_idx else place_idx[0]]][0]
    else:
        place = VERB_PLACE.get(verb, ctx.place)
    t_rel = min(max(action["start_s"] - t0, 0.0), TURN_SECONDS)
    observations: list[ObjectObservation] = []
    relations: list[SpatialRelation] = []
    ids = []
    for i, ((surface, cls), key) in enumerate(zip(pairs, keys)):
        props, extra = split_noun(surface)
        adjectives = [v for v in (props.color, props.size, props.material) if v]
        name = object_name(surface, key, adjectives, extra)
        object_id = slug(" ".join(adjectives + [noun_phrase(key)]))
        ids.append(object_id)
        fixture = key in PLACE_NOUNS
        is_target = (i == target or i in kept) and i != 0
        state = KEPT_STATE if is_target else VERB_STATE.get(verb, DEFAULT_STATE)
        held = None
        if not fixture and not is_target:
            if verb in HOLDING_VERBS:
                held = "hand"
            elif verb not in RELEASING_VERBS and object_id in ctx.held:
                held = "hand"
        observations.append(ObjectObservation(
            object_id=object_id, name=name, kind=slug(noun_phrase(key)), category=classes.noun_category.get(cls, ""),
            visual_properties=props, location=PLACE_NOUNS[key][0] if fixture else place,
            zone=PLACE_NOUNS[key][1] if fixture else "", state=state, held_by=held,
            is_fixture=fixture, t_rel=round(t_rel, 2), action=verb, narration=action["narration"],
            narration_id=action["narration_id"],
        ))
    if rel and target is not None and target > 0 and observations:
        subject, obj = observations[0], observations[target]
        subject.relative_to, subject.relation = obj.object_id, rel[0]
        if obj.is_fixture:
            subject.zone = obj.zone
        relations.append(SpatialRelation(subject=subject.object_id, relation=rel[0], object=obj.object_id))
    for o in observations:
        if o.is_fixture:
            continue
        if verb in HOLDING_VERBS:
            ctx.held[o.object_id] = (o, -1)
        elif verb in RELEASING_VERBS:
            ctx.held.pop(o.object_id, None)
    ctx.place = place
    return observations, place, relations


def perceive_video(
    participant: str,
    video_id: str,
    actions: Iterable[dict],
    duration: float,
    classes: ClassTables,
) -> Iterator[LayeredSegment]:
    """Cut one video into 10 s turns and yield one validated layered record per turn.

    `actions` are rows of `load_annotations` for this video (any order).
    """
    acts = sorted(actions, key=lambda a: (a["start_s"], a["stop_s"], a["narration_id"]))
    end = max([duration] + [a["start_s"] + 1e-6 for a in acts])
    n_turns = max(1, math.ceil(end / TURN_SECONDS))
    by_turn: dict[int, list[dict]] = {}
    for a in acts:
        by_turn.setdefault(min(int(a["start_s"] // TURN_SECONDS), n_turns - 1), []).append(a)
    ctx = _Context()
    for turn in range(n_turns):
        t0 = turn * TURN_SECONDS
        carried = ctx.summary(participant)
        start_place = ctx.place
        objects: list[ObjectObservation] = []
        relations: list[SpatialRelation] = []
        steps: list[ActionStep] = []
        place_votes: Counter[str] = Counter()
        for a in by_turn.get(turn, []):
            obs, place, rels = _observe_action(a, t0, ctx, classes)
            objects.extend(obs)
            relations.extend(rels)
            place_votes[place] += 1
            steps.append(ActionStep(
                timestamp=round(min(max(a["start_s"] - t0, 0.0), TURN_SECONDS), 2),
                end=round(max(a["stop_s"] - t0, 0.0), 2), action=a["verb"],
                object=noun_phrase(a["noun"]), narration=a["narration"],
                narration_id=a["narration_id"],
            ))
        seen = {o.object_id for o in objects}
        for object_id, (held_obs, since) in list(ctx.held.items()):
            if since == -1:
                ctx.held[object_id] = (held_obs, turn)
                continue
            if turn - since > HELD_CARRY_TURNS:
                del ctx.held[object_id]
                continue
            if object_id not in seen:
                objects.append(held_obs.model_copy(update={
                    "state": "held", "held_by": "hand", "location": start_place, "zone": "",
                    "relative_to": "", "relation": "", "t_rel": 0.0, "action": "",
                    "narration": "(still in hand)", "narration_id": "",
                }))
        location = place_votes.most_common(1)[0][0] if place_votes else start_place
        places = list(dict.fromkeys([location, *place_votes]))
        zones = _zones(objects)
        summary = "; ".join(s.narration for s in steps[:8]) + (f" (+{len(steps) - 8} more)" if len(steps) > 8 else "")
        narrative = " ".join(f"[{s.timestamp:.1f}-{min(s.end, 99.9):.1f}s] {s.narration}." for s in steps)
        if steps:
            ctx.recent.append(summary[:80])
        yield LayeredSegment(
            participant_id=participant, video_id=video_id, turn_id=turn, t_start=t0,
            t_end=min(t0 + TURN_SECONDS, max(end, t0)),
            environment=EnvironmentLayer(
                layout_description=f"{PLACE_NAMES.get(location, location)}"
                + (f" ({', '.join(zones)})" if zones else ""),
                location_id=location, places=places, zones=zones,
                spatial_relations=relations, features=sorted(zones),
            ),
            activity=ActivityLayer(
                summary=summary or "no narrated action", detailed_narrative=narrative,
                action_breakdown=steps,
            ),
            objects=objects,
            working_summary=carried,
        )


def _zones(objects) -> dict[str, Zone]:
    """Each fixture's zone, anchored on it, with the other objects observed in that zone."""
    zones: dict[str, Zone] = {}
    for o in objects:
        if o.is_fixture:
            zones.setdefault(o.zone, Zone(anchor=o.object_id, position=o.location))
    for o in objects:
        if not o.is_fixture and o.zone in zones and o.object_id not in zones[o.zone].contents:
            zones[o.zone].contents.append(o.object_id)
    return zones


class MomentContext(_Context):
    """What perception carries between the moments of one video that `perceive_moment` reads
    one at a time (the live path: `memora remember`)."""


def perceive_moment(participant: str, video_id: str, turn: int, action: dict, ctx: MomentContext,
                    classes: ClassTables) -> LayeredSegment:
    """One narrated moment (an action row, as `load_annotations` or perceive/narrations.py make
    it) -> one layered record spanning the action's own start and end, with `ctx` carried from
    the video's earlier moments (place, objects in hand, recent actions). The observation is
    read exactly as `perceive_video` reads an action; what differs is the span: a 10 s turn
    there, the moment here."""
    t0 = float(action["start_s"])
    carried = ctx.summary(participant)
    start_place = ctx.place
    obs, place, relations = _observe_action(action, t0, ctx, classes)
    for o in obs:
        if o.object_id in ctx.held and ctx.held[o.object_id][1] == -1:
            ctx.held[o.object_id] = (ctx.held[o.object_id][0], turn)
    seen = {o.object_id for o in obs}
    objects = list(obs)
    for object_id, (held_obs, since) in list(ctx.held.items()):
        if since == -1:
            ctx.held[object_id] = (held_obs, turn)
        elif turn - since > HELD_CARRY_TURNS:
            del ctx.held[object_id]
        elif object_id not in seen:
            objects.append(held_obs.model_copy(update={
                "state": "held", "held_by": "hand", "location": start_place, "zone": "", "relative_to": "",
                "relation": "", "t_rel": 0.0, "action": "", "narration": "(still in hand)", "narration_id": ""}))
    zones = _zones(objects)
    end = max(float(action["stop_s"]), t0)
    step = ActionStep(timestamp=0.0, end=round(end - t0, 2), action=action["verb"], object=noun_phrase(action["noun"]),
                      narration=action["narration"], narration_id=action["narration_id"])
    ctx.recent.append(action["narration"][:80])
    return LayeredSegment(
        participant_id=participant, video_id=video_id, turn_id=turn, t_start=t0, t_end=end,
        environment=EnvironmentLayer(
            layout_description=f"{PLACE_NAMES.get(place, place)}" + (f" ({', '.join(zones)})" if zones else ""),
            location_id=place, places=[place], zones=zones, spatial_relations=relations, features=sorted(zones)),
        activity=ActivityLayer(summary=action["narration"], detailed_narrative=f"[0.0-{min(end - t0, 99.9):.1f}s] "
                               f"{action['narration']}.", action_breakdown=[step]),
        objects=objects, working_summary=carried,
    )

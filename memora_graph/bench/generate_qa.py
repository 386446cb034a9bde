"""EAM-QA generation from annotations: SPref, SHabit, SRoutine and ERecall, with no LLM.

The paper's pipeline mines statistics, prompts an LLM to word items and filters them with a
verifier. Here every item is built by a rule from the participant's `Behaviour` index, so the
evidence gates are exact rather than requested in a prompt:

- SPref (single-hop): a dominant put-location, take-source, tool, object-for-a-verb or
  verb-for-an-object, seen >= `min_count` times in >= 2 videos and clearly ahead of the
  runner-up. Multi-hop (depth d): the put-location that follows a chain of d-1 actions.
- SHabit: after a trigger (a chain of `depth` actions; single-hop = one action) seen >= 4
  times in >= 2 videos, the habitual next action, repeated in >= 2 videos; for chains the
  context must change the prediction of the last action alone.
- SRoutine (single-hop): a 3-step ordered chain recurring in >= 2 videos with >= 2
  characteristic steps (universal flows such as pick-up -> put-down, open -> close are
  rejected). Multi-hop (depth d): the d steps that dominantly follow a trigger.
- ERecall: one item per video on its main activity; multi-hop (depth d): which ordered
  d-step sequence the participant performed with an object in that video.

Distractors come from the participant's own other behaviour and are checked to have zero
support for the asked fact, so exactly one option is right. Every item keeps its evidence in
`audit` (never shown to the answering agent).
"""

from __future__ import annotations

import itertools
import random
import re
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Any

from memora_graph.bench.behaviour import (
    ActionClass, Behaviour, Evidence, action_phrase, clock, noun_text, object_text, place_preposition,
    pronoun_phrase, sequence_phrase, verb_phrase,
)

# Objects too generic to make an activity label or an object-preference answer on their own.
LOW_INFO_NOUNS = frozenset({"hand", "tap", "water"})

_DEPTH_WORD = {2: "two", 3: "three"}


@dataclass
class QaThresholds:
    """Evidence gates (paper Table "question types ... evidence thresholds")."""

    min_videos: int = 2  # cross-video types need support in at least two videos
    min_count: int = 3  # "repeated observations" for a preference or a habit response
    min_trigger: int = 4  # SHabit: trigger occurrences
    min_share: float = 0.3  # SHabit: response share among everything that follows the trigger
    min_chain_count: int = 2  # multi-hop semantic chains: occurrences
    min_chain_share: float = 0.5  # multi-hop semantic chains: share of the dominant continuation
    lead_ratio: float = 1.5  # SPref: the preferred option outnumbers the runner-up by this factor


@dataclass
class QuestionCandidate:
    qa_type: str
    depth: int
    template: str
    stem: str
    answer: str
    distractors: list[str]
    video_ids: list[str]
    strength: float
    evidence: dict
    support_keys: list[str]
    video_id: str = ""
    topic: str = ""  # what the item is about (object, trigger or video); spreads selection over topics

    def dedup_text(self) -> str:
        return self.stem

    def claim(self) -> str:
        return _normalized(self.answer)


def _cap(text: str) -> str:
    return text[:1].upper() + text[1:]


def _dominant(options: dict, lead_ratio: float = 1.0) -> tuple:
    """(best key, best Evidence, runner-up count) or (None, None, 0) when there is no clear leader."""
    ranked = sorted(options.items(), key=lambda kv: (-kv[1].count, str(kv[0])))
    if not ranked:
        return None, None, 0
    best, ev = ranked[0]
    second = ranked[1][1].count if len(ranked) > 1 else 0
    if ev.count <= second or ev.count < lead_ratio * second:
        return None, None, second
    return best, ev, second


def _pick(rng: random.Random, pool: list[str], k: int, exclude: set[str]) -> list[str]:
    """k distinct texts from a priority-ordered pool; the order within the top of the pool varies with the seed."""
    seen = {e.lower() for e in exclude}
    uniq = []
    for text in pool:
        if text.lower() not in seen:
            seen.add(text.lower())
            uniq.append(text)
    head = uniq[: max(k * 2, k)]
    rng.shuffle(head)
    return (head + uniq[len(head):])[:k]


class QaGenerator:
    def __init__(self, behaviour: Behaviour, rng: random.Random, thresholds: QaThresholds | None = None):
        self.b = behaviour
        self.pid = behaviour.participant_id
        self.rng = rng
        self.t = thresholds or QaThresholds()
        self.frequent = sorted(
            (a for a, ev in behaviour.action_evidence.items() if ev.count >= 2 and a.phrasable),
            key=lambda a: (-behaviour.action_evidence[a].count, a),
        )
        self.nonfiller = [a for a in self.frequent if not a.is_filler]

    # -- shared helpers -------------------------------------------------------------------------
    def _distract_actions(self, avoid: set[ActionClass], prefer_nouns: set[str], k: int = 3) -> list[ActionClass]:
        same = [a for a in self.frequent if a.noun in prefer_nouns and a not in avoid]
        rest = [a for a in self.frequent if a.noun not in prefer_nouns and a not in avoid]
        pool = same[:6] + rest[:12]
        texts = _pick(self.rng, [a.key() for a in pool], k, set())
        by_key = {a.key(): a for a in pool}
        return [by_key[t] for t in texts]

    def all(self) -> list[QuestionCandidate]:
        out: list[QuestionCandidate] = []
        out += self.spref()
        out += self.shabit()
        out += self.sroutine()
        out += self.erecall()
        for c in out:
            ev = c.evidence
            if c.qa_type == "ERecall":
                c.topic = c.video_id
            elif c.qa_type == "SHabit":
                c.topic = ev["trigger"][-1]
            else:
                c.topic = str(ev.get("object") or ev.get("topic") or ev.get("trigger") or ev.get("action") or ev.get("verb"))
        return out

    # -- SPref ----------------------------------------------------------------------------------
    def spref(self) -> list[QuestionCandidate]:
        out = []
        t = self.t
        known_places = Counter()
        for (kind, _), places in self.b.places.items():
            for place, ev in places.items():
                known_places[place] += ev.count
        place_pool = [p for p, _ in sorted(known_places.items(), key=lambda kv: (-kv[1], kv[0]))]
        for (kind, noun), places in sorted(self.b.places.items()):
            best, ev, second = _dominant(places, t.lead_ratio)
            if best is None or ev.count < t.min_count or len(ev.videos) < t.min_videos:
                continue
            taking = kind == "take"
            observed = set(places) | set(self.b.places.get(("take" if not taking else "put", noun), {}))
            others = [p for p in place_pool if p not in observed and p != noun]
            if len(others) < 3:
                continue
            distract = _pick(self.rng, others, 3, set())

            def say(place: str) -> str:
                prep = place_preposition("", place, taking=taking)
                return f"{_cap(prep)} the {noun_text(place)}"

            stem = (f"Where does {self.pid} usually take the {noun_text(noun)} from?" if taking
                    else f"Where does {self.pid} usually put the {noun_text(noun)}?")
            out.append(QuestionCandidate(
                "SPref", 1, f"{kind}_location", stem, say(best), [say(p) for p in distract], ev.videos,
                ev.count / (ev.count + second), {**ev.audit(), "runner_up_count": second, "object": noun, "place": best},
                [f"{kind}:{noun}@{best}"],
            ))
        tool_pool = Counter()
        for action, tools in self.b.tools.items():
            for tool, ev in tools.items():
                tool_pool[tool] += ev.count
        tool_rank = [p for p, _ in sorted(tool_pool.items(), key=lambda kv: (-kv[1], kv[0]))]
        for action, tools in sorted(self.b.tools.items()):
            best, ev, second = _dominant(tools, t.lead_ratio)
            if best is None or ev.count < t.min_count or len(ev.videos) < t.min_videos:
                continue
            others = [p for p in tool_rank if p not in tools and p != action.noun]
            if len(others) < 3:
                continue
            distract = _pick(self.rng, others, 3, set())
            stem = f"What does {self.pid} usually use to {verb_phrase(action.verb, 'base')} {object_text(action.noun)}?"
            out.append(QuestionCandidate(
                "SPref", 1, "tool", stem, f"The {noun_text(best)}", [f"The {noun_text(p)}" for p in distract],
                ev.videos, ev.count / (ev.count + second),
                {**ev.audit(), "runner_up_count": second, "action": action.key(), "tool": best},
                [f"tool:{action.key()}@{best}"],
            ))
        out += self._spref_object_for_verb()
        out += self._spref_verb_for_object()
        out += self._spref_chained_location()
        return out

    def _spref_object_for_verb(self) -> list[QuestionCandidate]:
        out, t = [], self.t
        by_verb: dict[str, dict[str, Evidence]] = defaultdict(dict)
        for a, ev in self.b.action_evidence.items():
            if not a.is_filler and a.noun not in LOW_INFO_NOUNS:
                by_verb[a.verb][a.noun] = ev
        handled = sorted((n for n in self.b.noun_evidence if n not in LOW_INFO_NOUNS),
                         key=lambda n: (-self.b.noun_evidence[n].count, n))
        for verb, nouns in sorted(by_verb.items()):
            best, ev, second = _dominant(nouns, t.lead_ratio)
            if best is None or ev.count < t.min_count or len(ev.videos) < t.min_videos:
                continue
            others = [n for n in handled if n not in nouns and self.b.category(n) == self.b.category(best)]
            others += [n for n in handled if n not in nouns and n not in others]
            if len(others) < 3:
                continue
            distract = _pick(self.rng, others[:10], 3, set())
            stem = f"Across sessions, which item does {self.pid} {verb_phrase(verb, 'base')} most often?"
            out.append(QuestionCandidate(
                "SPref", 1, "object_for_verb", stem, f"The {noun_text(best)}",
                [f"The {noun_text(n)}" for n in distract], ev.videos, ev.count / (ev.count + second),
                {**ev.audit(), "runner_up_count": second, "verb": verb, "object": best},
                [f"action:{ActionClass(verb, best).key()}"],
            ))
        return out

    def _spref_verb_for_object(self) -> list[QuestionCandidate]:
        out, t = [], self.t
        by_noun: dict[str, dict[str, Evidence]] = defaultdict(dict)
        for a, ev in self.b.action_evidence.items():
            if not a.is_filler:
                by_noun[a.noun][a.verb] = ev
        verbs_used = Counter()
        for a, ev in self.b.action_evidence.items():
            if not a.is_filler:
                verbs_used[a.verb] += ev.count
        verb_rank = [v for v, _ in sorted(verbs_used.items(), key=lambda kv: (-kv[1], kv[0]))]
        for noun, verbs in sorted(by_noun.items()):
            if self.b.category(noun) == "hand":
                continue
            best, ev, second = _dominant(verbs, t.lead_ratio)
            if best is None or ev.count < t.min_count or len(ev.videos) < t.min_videos:
                continue
            others = [v for v in verb_rank if v not in verbs]
            if len(others) < 3:
                continue
            distract = _pick(self.rng, others[:10], 3, set())
            stem = f"What does {self.pid} most often do with the {noun_text(noun)}?"
            say = pronoun_phrase
            out.append(QuestionCandidate(
                "SPref", 1, "verb_for_object", stem, say(best), [say(v) for v in distract], ev.videos,
                ev.count / (ev.count + second),
                {**ev.audit(), "runner_up_count": second, "object": noun, "verb": best},
                [f"action:{ActionClass(best, noun).key()}"],
            ))
        return out

    def _spref_chained_location(self) -> list[QuestionCandidate]:
        """Depth d: where the object goes after a chain of d-1 actions (chain + put with a place)."""
        out, t = [], self.t
        table: dict[tuple, dict[str, Evidence]] = defaultdict(lambda: defaultdict(Evidence))
        for video in self.b.videos:
            runs = self.b.runs_by_video[video]
            for i, run in enumerate(runs):
                put = [s for s in run.steps if s.place and s.action.verb in ("put", "insert", "throw")]
                if not put:
                    continue
                for d in (2, 3):
                    if i - (d - 1) < 0:
                        continue
                    chain = tuple(r.action for r in runs[i - d + 1:i])
                    table[(chain, run.action)][put[0].place].add(put[0])
        all_places = sorted({p for places in table.values() for p in places})
        for (chain, put_action), places in sorted(table.items()):
            best, ev, second = _dominant(places)
            if best is None or ev.count < t.min_chain_count or len(ev.videos) < t.min_videos:
                continue
            if ev.count / sum(e.count for e in places.values()) < t.min_chain_share:
                continue
            if best in {a.noun for a in chain}:
                continue  # "after opening the bin, where does the box go?" would leak the answer
            observed = set(self.b.places.get(("put", put_action.noun), {}))
            others = [p for p in all_places if p not in observed and p != put_action.noun]
            others += [p for p in sorted(self.b.noun_evidence) if self.b.category(p) in ("furniture", "storage", "appliances")
                       and p not in observed and p not in others]
            if len(others) < 3:
                continue
            distract = _pick(self.rng, others, 3, set())
            d = len(chain) + 1
            context = ", then ".join(action_phrase(a) for a in chain)
            stem = f"After {self.pid} {context}, where do they usually put the {noun_text(put_action.noun)}?"
            say = lambda p: f"{_cap(place_preposition('', p))} the {noun_text(p)}"  # noqa: E731
            out.append(QuestionCandidate(
                "SPref", d, "chained_location", stem, say(best), [say(p) for p in distract], ev.videos,
                ev.count, {**ev.audit(), "chain": [a.key() for a in chain], "object": put_action.noun, "place": best},
                [f"put:{put_action.noun}@{best}"] + [f"action:{a.key()}" for a in chain],
            ))
        return out

    # -- SHabit ---------------------------------------------------------------------------------
    def shabit(self) -> list[QuestionCandidate]:
        out, t = [], self.t
        for chain, nexts in sorted(self.b.chain_next.items()):
            d = len(chain)
            total = sum(e.count for e in nexts.values())
            if total < (t.min_trigger if d == 1 else t.min_chain_count):
                continue
            best, ev, second = _dominant(nexts)
            if best is None or best in chain or not all(a.phrasable for a in (*chain, best)):
                continue
            if d == 1:
                trig = self.b.action_evidence[chain[0]]
                if trig.count < t.min_trigger or len(trig.videos) < t.min_videos:
                    continue
                if ev.count < t.min_count or len(ev.videos) < t.min_videos or ev.count / total < t.min_share:
                    continue
                if chain[0].is_filler and best.is_filler and chain[0].noun == best.noun:
                    continue  # take X -> put X, open X -> close X: universal, not a habit
            else:
                if ev.count < t.min_chain_count or len(ev.videos) < t.min_videos or ev.count / total < t.min_chain_share:
                    continue
                alone, alone_ev, _ = _dominant(self.b.chain_next[chain[-1:]])
                alone_total = sum(e.count for e in self.b.chain_next[chain[-1:]].values())
                alone_share = self.b.chain_next[chain[-1:]][best].count / alone_total if alone_total else 0
                if alone == best and alone_share >= ev.count / total:
                    continue  # the earlier steps add nothing: not a multi-hop question
                if all(a.is_filler for a in (*chain, best)):
                    continue
            avoid = set(nexts) | set(chain)
            distract = self._distract_actions(avoid, {best.noun, chain[-1].noun})
            if len(distract) < 3:
                continue
            context = ", then ".join(action_phrase(a) for a in chain)
            stem = f"After {self.pid} {context}, what do they typically do next?"
            out.append(QuestionCandidate(
                "SHabit", d, "trigger_next" if d == 1 else "chain_next", stem, _cap(action_phrase(best)),
                [_cap(action_phrase(a)) for a in distract], ev.videos, ev.count / total + ev.count / 100,
                {**ev.audit(), "trigger": [a.key() for a in chain], "response": best.key(),
                 "total_trigger_followups": total, "runner_up_count": second,
                 **({"trigger_count": self.b.action_evidence[chain[0]].count,
                     "trigger_videos": self.b.action_evidence[chain[0]].videos} if d == 1 else {})},
                ["chain:" + " > ".join(a.key() for a in (*chain, best))],
            ))
        return out

    # -- SRoutine -------------------------------------------------------------------------------
    def _sequence_distractors(self, seq: tuple[ActionClass, ...], observed, k: int = 3,
                              forbid: tuple[ActionClass, ...] = ()) -> list[tuple[ActionClass, ...]]:
        """Reorderings and one-step substitutions of seq that `observed(candidate)` says never happened."""
        options = []
        for perm in itertools.permutations(seq):
            if perm != seq and len(set(perm)) == len(perm) and not observed(perm):
                options.append(perm)
        nouns = {a.noun for a in seq}
        subs = [a for a in self.frequent if a.noun in nouns and a not in seq and a not in forbid][:6]
        subs += [a for a in self.nonfiller if a not in seq and a not in subs and a not in forbid][:6]
        for i in range(len(seq)):
            for a in subs:
                cand = seq[:i] + (a,) + seq[i + 1:]
                if len(set(cand)) == len(cand) and not observed(cand):
                    options.append(cand)
        # at most two reorderings so that the options stay "different approaches", not only shuffles
        same = set(seq)
        perms = [o for o in options if set(o) == same]
        others = [o for o in options if set(o) != same]
        self.rng.shuffle(perms)
        self.rng.shuffle(others)
        chosen = perms[:2] + others
        uniq = []
        for o in chosen:
            if o not in uniq:
                uniq.append(o)
        picked = uniq[:k]
        if len(picked) < k:
            picked += [o for o in perms[2:] if o not in picked][: k - len(picked)]
        return picked

    def sroutine(self) -> list[QuestionCandidate]:
        out, t = [], self.t
        routines: dict[tuple[ActionClass, ...], Evidence] = defaultdict(Evidence)
        conts: dict[tuple[ActionClass, int], dict[tuple[ActionClass, ...], Evidence]] = defaultdict(lambda: defaultdict(Evidence))
        for video in self.b.videos:
            runs = self.b.runs_by_video[video]
            for i in range(len(runs)):
                seq = tuple(r.action for r in runs[i:i + 3])
                if len(seq) == 3 and len(set(seq)) == 3:
                    routines[seq].add(runs[i].steps[0])
                for d in (2, 3):
                    cont = tuple(r.action for r in runs[i + 1:i + 1 + d])
                    if len(cont) == d:
                        conts[(runs[i].action, d)][cont].add(runs[i + 1].steps[0])
        for seq, ev in sorted(routines.items()):
            if ev.count < t.min_chain_count or len(ev.videos) < t.min_videos:
                continue
            if sum(not a.is_filler for a in seq) < 2 or not all(a.phrasable for a in seq):
                continue  # universal flows (pick-up -> put-down, open -> close) are not routines
            topics = Counter(a.noun for a in seq if not a.is_filler and a.noun not in LOW_INFO_NOUNS)
            if not topics:
                continue
            topic = sorted(topics.items(), key=lambda kv: (-kv[1], kv[0]))[0][0]
            distract = self._sequence_distractors(seq, self.b.occurs_anywhere)
            if len(distract) < 3:
                continue
            stem = f"Which sequence of steps does {self.pid} repeat across sessions when handling the {noun_text(topic)}?"
            out.append(QuestionCandidate(
                "SRoutine", 1, "recurring_sequence", stem, sequence_phrase(seq) + ".",
                [sequence_phrase(s) + "." for s in distract], ev.videos, ev.count,
                {**ev.audit(), "sequence": [a.key() for a in seq], "topic": topic},
                ["chain:" + " > ".join(a.key() for a in seq)],
            ))
        for (trigger, d), options in sorted(conts.items()):
            best, ev, second = _dominant(options)
            if best is None or ev.count < t.min_chain_count or len(ev.videos) < t.min_videos:
                continue
            if len(set(best)) < d or trigger in best or sum(not a.is_filler for a in best) < 1:
                continue
            if not all(a.phrasable for a in (trigger, *best)):
                continue
            if all(a.is_filler for a in (trigger, *best)):
                continue
            follows = lambda cand, trig=trigger: self.b.occurs_anywhere((trig, *cand))  # noqa: E731
            distract = self._sequence_distractors(best, follows, forbid=(trigger,))
            if len(distract) < 3:
                continue
            stem = (f"After {self.pid} {action_phrase(trigger)}, which {_DEPTH_WORD[d]} steps follow, in order?")
            out.append(QuestionCandidate(
                "SRoutine", d, "continuation", stem, sequence_phrase(best) + ".",
                [sequence_phrase(s) + "." for s in distract], ev.videos, ev.count,
                {**ev.audit(), "trigger": trigger.key(), "continuation": [a.key() for a in best],
                 "runner_up_count": second},
                ["chain:" + " > ".join(a.key() for a in (trigger, *best))],
            ))
        return out

    # -- ERecall --------------------------------------------------------------------------------
    def _video_label(self, video: str) -> tuple[list[ActionClass], str] | None:
        counts = self.b.video_action_counts[video]
        first = {}
        for i, run in enumerate(self.b.runs_by_video[video]):
            first.setdefault(run.action, i)
        ranked = sorted((a for a in counts if not a.is_filler and a.noun not in LOW_INFO_NOUNS),
                        key=lambda a: (-counts[a], first[a]))
        if not ranked or counts[ranked[0]] < 2:
            return None
        top = ranked[:2]
        label = " and ".join(action_phrase(a, "gerund") for a in top)
        return top, _cap(label)

    def erecall(self) -> list[QuestionCandidate]:
        out = []
        labels = {v: self._video_label(v) for v in self.b.videos}
        for video in self.b.videos:
            if labels[video] is None:
                continue
            top, label = labels[video]
            counts = self.b.video_action_counts[video]
            pool = []
            for other in self.b.videos:
                if other != video and labels[other] and all(counts[a] == 0 for a in labels[other][0]):
                    pool.append(labels[other][1])
            absent = [a for a in self.nonfiller if counts[a] == 0 and a.noun not in LOW_INFO_NOUNS]
            for a, b in zip(absent[0::2], absent[1::2]):
                pool.append(_cap(f"{action_phrase(a, 'gerund')} and {action_phrase(b, 'gerund')}"))
            distract = _pick(self.rng, pool, 3, {label})
            if len(distract) < 3:
                continue
            ev = Evidence()
            for run in self.b.runs_by_video[video]:
                if run.action in top:
                    ev.add(run.steps[0])
            out.append(QuestionCandidate(
                "ERecall", 1, "main_activity", f"What was {self.pid} mainly doing in video {video}?", label,
                distract, [video], float(counts[top[0]]),
                {**ev.audit(), "top_actions": {a.key(): counts[a] for a in top}}, [f"action:{a.key()}" for a in top],
                video_id=video,
            ))
        for d in (2, 3):
            for video in self.b.videos:
                chains = []
                for chain in self.b.chains(video, d):
                    seq = tuple(r.action for r in chain)
                    if len(set(seq)) < d or all(a.is_filler for a in seq) or not all(a.phrasable for a in seq):
                        continue
                    nouns = Counter(a.noun for a in seq)
                    noun = nouns.most_common(1)[0][0]
                    if noun in LOW_INFO_NOUNS:
                        continue
                    chains.append((sum(not a.is_filler for a in seq), chain, noun))
                self.rng.shuffle(chains)
                chains.sort(key=lambda c: -c[0])
                for _, chain, noun in chains[:4]:
                    seq = tuple(r.action for r in chain)
                    distract = self._sequence_distractors(seq, lambda cand, v=video: self.b.occurs_in_video(v, cand))
                    if len(distract) < 3:
                        continue
                    ev = Evidence()
                    for run in chain:
                        ev.add(run.steps[0])
                    stem = f"In video {video}, {self.pid} handled {object_text(noun)}. Which sequence did they perform?"
                    out.append(QuestionCandidate(
                        "ERecall", d, "video_sequence", stem, sequence_phrase(seq) + ".",
                        [sequence_phrase(s) + "." for s in distract], [video], float(d),
                        {**ev.audit(), "sequence": [a.key() for a in seq], "start": clock(chain[0].start_s)},
                        ["chain:" + " > ".join(a.key() for a in seq)], video_id=video,
                    ))
        return out


def rewrite_participant(text: str, donor: str, target: str) -> str:
    """Donor -> target participant mentions; donor video ids become masked target ids (PXX_???)."""
    text = re.sub(rf"\b{donor}_\d+\b", f"{target}_???", text)
    return re.sub(rf"\b{donor}\b", target, text)


# ---------------------------------------------------------------------------------------------
# Curation: rank, exact and semantic dedup, quotas and caps, E-correct controls, assembly
# ---------------------------------------------------------------------------------------------

@dataclass
class QaConfig:
    """Per-participant quotas (paper: 8 single-hop + 8 multi-hop per semantic type before x3
    overproduction, one ERecall item per video, 50% per-type cap, ~20% E-correct controls)."""

    single_hop: dict[str, int] = field(default_factory=lambda: {"SPref": 24, "SHabit": 24, "SRoutine": 24})
    erecall_per_video: int = 1
    multi_hop_per_depth: int = 12  # per type, for depth 2 and for depth 3
    type_share_cap: float = 0.5
    dedup_threshold: float = 0.95
    unanswerable_ratio: float = 0.2  # share of the final panel
    thresholds: QaThresholds = field(default_factory=QaThresholds)

    def quota(self, qa_type: str, depth: int, n_videos: int) -> int:
        if depth > 1:
            return self.multi_hop_per_depth
        if qa_type == "ERecall":
            return self.erecall_per_video * n_videos
        return self.single_hop.get(qa_type, 0)


def _normalized(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", " ", text.lower()).strip()


def rank_candidates(cands: list[QuestionCandidate], rng: random.Random) -> dict[tuple[str, int], list[QuestionCandidate]]:
    """Exact dedup, then per (type, depth): strongest first, spread round-robin over topics."""
    seen, unique = set(), []
    for c in cands:
        key = (_normalized(c.stem), _normalized(c.answer))
        if key not in seen:
            seen.add(key)
            unique.append(c)
    groups: dict[tuple[str, int], list[QuestionCandidate]] = defaultdict(list)
    for c in unique:
        groups[(c.qa_type, c.depth)].append(c)
    ranked = {}
    for key in sorted(groups):
        items = groups[key]
        tiebreak = {id(c): rng.random() for c in items}
        items.sort(key=lambda c: (-c.strength, tiebreak[id(c)]))
        by_topic: dict[str, list[QuestionCandidate]] = {}
        for c in items:
            by_topic.setdefault(c.topic, []).append(c)
        order = []
        queues = list(by_topic.values())
        while queues:
            order += [q.pop(0) for q in queues]
            queues = [q for q in queues if q]
        ranked[key] = order
    return ranked


class VectorCache:
    """Embeds each distinct text once; priming many texts in one call keeps model calls few."""

    def __init__(self, embedder):
        self.embedder = embedder
        self.vectors: dict[str, Any] = {}

    def prime(self, texts: list[str]) -> None:
        new = [t for t in dict.fromkeys(texts) if t not in self.vectors]
        if new:
            for text, vec in zip(new, self.embedder.encode(new)):
                self.vectors[text] = vec

    def get(self, texts: list[str]) -> list:
        self.prime(texts)
        return [self.vectors[t] for t in texts]


def pool_margin(quota: int) -> int:
    """How many candidates beyond the quota to consider up front (dedup drops are replaced from these)."""
    return max(4, quota // 3)


def dedup_pool(ranked: dict[tuple[str, int], list[QuestionCandidate]], config: QaConfig, n_videos: int) -> list[str]:
    """Stems select_answerable will most likely embed: those whose answer another candidate shares
    (only they can be duplicates). Used to prime a VectorCache with one model call."""
    pool = []
    for key, items in ranked.items():
        quota = config.quota(key[0], key[1], n_videos)
        pool += items[: quota + pool_margin(quota)]
    claims = Counter(c.claim() for c in pool)
    return [c.dedup_text() for c in pool if claims[c.claim()] > 1]


def select_answerable(ranked: dict[tuple[str, int], list[QuestionCandidate]], config: QaConfig, n_videos: int,
                      vectors: VectorCache | None = None) -> tuple[list[QuestionCandidate], dict]:
    """Fill each (type, depth) quota in rank order, then apply the per-type share cap.

    Semantic dedup (with `vectors`): stems at cosine >= threshold form a near-duplicate cluster;
    the paper lets an LLM pick which members to keep "without collapsing legitimately distinct
    probes". The rule here: a candidate is dropped when a kept item of the participant makes the
    same claim (same normalized correct answer) with a stem at cosine >= threshold; near-identical
    templates asking about different facts stay. Without `vectors` only exact duplicates go.
    Returns (kept, stats).
    """
    import numpy as np

    kept: list[QuestionCandidate] = []
    kept_by_claim: dict[str, list[QuestionCandidate]] = defaultdict(list)
    dropped_semantic = 0
    for key, items in ranked.items():
        quota = config.quota(key[0], key[1], n_videos)
        chosen = 0
        for c in items:
            if chosen >= quota:
                break
            same_claim = kept_by_claim.get(c.claim(), [])
            if vectors is not None and same_claim:
                vecs = vectors.get([c.dedup_text()] + [k.dedup_text() for k in same_claim])
                if float(np.max(np.stack(vecs[1:]) @ vecs[0])) >= config.dedup_threshold:
                    dropped_semantic += 1
                    continue
            kept.append(c)
            kept_by_claim[c.claim()].append(c)
            chosen += 1
    kept, capped = apply_type_cap(kept, config.type_share_cap)
    return kept, {"dropped_semantic_duplicates": dropped_semantic, "dropped_by_type_cap": capped}


def apply_type_cap(items: list[QuestionCandidate], share: float) -> tuple[list[QuestionCandidate], int]:
    """Drop the lowest-ranked items of any type above `share` of the participant's items.

    A participant whose annotations support a single type keeps it: dropping cannot balance it.
    """
    items = list(items)
    dropped = 0
    while True:
        counts = Counter(c.qa_type for c in items)
        if len(counts) <= 1:
            return items, dropped
        qa_type, n = max(counts.items(), key=lambda kv: (kv[1], kv[0]))
        if n <= share * len(items):
            return items, dropped
        last = max(i for i, c in enumerate(items) if c.qa_type == qa_type)
        del items[last]
        dropped += 1


def balanced_letters(n: int, rng: random.Random) -> list[int]:
    """Correct-answer positions 0-3, each used n//4 or n//4 + 1 times, in seeded order."""
    letters = [i % 4 for i in range(n)]
    rng.shuffle(letters)
    return letters


def control_quota(n_answerable: int, ratio: float) -> int:
    """Controls so that they are `ratio` of the final panel (0.2 -> one per four answerable)."""
    return int(round(n_answerable * ratio / (1 - ratio))) if n_answerable else 0


def allocate(total: int, weights: dict[str, int]) -> dict[str, int]:
    """Largest-remainder split of total over keys in proportion to weights."""
    norm = sum(weights.values())
    if not norm:
        return {k: 0 for k in weights}
    raw = {k: total * w / norm for k, w in weights.items()}
    out = {k: int(v) for k, v in raw.items()}
    for k in sorted(raw, key=lambda k: (-(raw[k] - out[k]), k))[: total - sum(out.values())]:
        out[k] += 1
    return out


def select_controls(target: str, target_facts: set[str], answerable_types: Counter,
                    donor_pools: dict[str, list[QuestionCandidate]], n: int, rng: random.Random) -> list[tuple[str, QuestionCandidate]]:
    """E-correct controls: donor questions whose asked fact the target never shows."""
    wanted = allocate(n, {t: answerable_types.get(t, 0) for t in ("SPref", "SHabit", "SRoutine", "ERecall")})
    offers: dict[str, list[tuple[str, QuestionCandidate]]] = defaultdict(list)
    for donor in sorted(donor_pools):
        if donor == target:
            continue
        for c in donor_pools[donor]:
            if not any(k in target_facts for k in c.support_keys):
                offers[c.qa_type].append((donor, c))
    for t in offers:
        rng.shuffle(offers[t])
        # alternate donors so that no single donor dominates a participant's controls
        by_donor: dict[str, list] = {}
        for d, c in offers[t]:
            by_donor.setdefault(d, []).append((d, c))
        order, queues = [], list(by_donor.values())
        while queues:
            order += [q.pop(0) for q in queues]
            queues = [q for q in queues if q]
        offers[t] = order
    chosen: list[tuple[str, QuestionCandidate]] = []
    stems = set()
    short = 0
    for t, k in wanted.items():
        got = 0
        for donor, c in offers.get(t, []):
            if got >= k:
                break
            stem = _normalized(rewrite_participant(c.stem, donor, target))
            if stem in stems:
                continue
            stems.add(stem)
            chosen.append((donor, c))
            got += 1
        short += k - got
    if short:  # a type without enough donor questions: fill from the others
        rest = [o for t in sorted(offers) for o in offers[t] if o not in chosen]
        for donor, c in rest:
            if short == 0:
                break
            stem = _normalized(rewrite_participant(c.stem, donor, target))
            if stem not in stems:
                stems.add(stem)
                chosen.append((donor, c))
                short -= 1
    return chosen

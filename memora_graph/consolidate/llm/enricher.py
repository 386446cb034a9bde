"""InfMem enrichment by a model: routine skills, then generated preferences, over one list of
evidence items (E001, ...: the rule episodes of every video, then the consolidated patterns)."""

from __future__ import annotations

from dataclasses import dataclass, field

from memora_graph.consolidate.llm.handles import Handles, EntityNames, resolve_refs
from memora_graph.consolidate.llm.model_step import ModelStep
from memora_graph.consolidate.llm.prompts import (
    ACTIVITY_TYPES, ALLOWED_SUBTYPES, ENRICHMENT_SYSTEM, PROMPT_VERSIONS, action_text, clip_text, short_number, evenly_sampled,
)
from memora_graph.consolidate.llm.replies import PreferenceItem, PreferencesReply, SkillItem, SkillsReply
from memora_graph.consolidate.llm.reply_records import normalized_activity, merge_videos
from memora_graph.consolidate.memory import ParticipantMemory
from memora_graph.consolidate.records import (
    ActionSequence, Consolidation, Enrichment, Episode, GeneratedPreference, RoutineSkill,
)
from memora_graph.consolidate.rules import RuleEnricher
from memora_graph.text import uniq


@dataclass
class _Evidence:
    """One enrichment evidence item: a rule episode or a consolidated pattern, and its segments."""

    segments: list[str]
    videos: dict[str, int]
    episode: Episode | None = None
    entities: list[str] = field(default_factory=list)


class LLMEnricher(ModelStep):
    """InfMem enrichment by a model: routine skills, then generated preferences, over one list of
    evidence items (the rule episodes of every video, then the consolidated patterns)."""

    role = "enrichment"

    def evidence(self, memory: ParticipantMemory, consolidation: Consolidation) -> tuple[str, Handles]:
        lim = self.limits
        rules = RuleEnricher()
        episodes = [ep for _, steps in sorted(memory.steps_by_video().items()) for ep in rules.episodes(steps)]
        handles = Handles("E", width=3)
        lines = []
        shown = evenly_sampled(episodes, lim.episodes)
        for ep in shown:
            video, segments = ep[0].video, uniq(s.segment for s in ep)
            item = _Evidence(segments, {video: 1},
                             Episode(video=video, t_start=round(ep[0].t, 2), t_end=round(ep[-1].t, 2), segments=segments),
                             uniq(o.entity for s in ep for o in s.objects))
            acts = "; ".join(action_text(s) for s in ep[: lim.steps_per_episode])
            if len(ep) > lim.steps_per_episode:
                acts += f"; ... ({len(ep) - lim.steps_per_episode} more)"
            lines.append(clip_text(f"{handles.add(item)} {video} {short_number(ep[0].t)}-{short_number(ep[-1].t)} s @{ep[0].location}: {acts}",
                               lim.line_chars))
        patterns = ([("storage", p, p.statement) for p in consolidation.storage_preferences]
                    + [("habit", h, h.habit) for h in consolidation.organizational_habits]
                    + [("workflow", w, w.pattern) for w in consolidation.workflow_patterns]
                    + [("action sequence", a, f"{a.title}: {'; '.join(a.steps)}") for a in consolidation.action_sequences])
        pattern_lines = []
        for kind, rec, statement in patterns[: lim.patterns]:
            segs = list(rec.segments) if isinstance(rec, ActionSequence) else list(rec.supporting_episodes)
            item = _Evidence(segs, dict(rec.videos), None, list(rec.entities))
            pattern_lines.append(clip_text(f"{handles.add(item)} [{kind}, {len(rec.videos)} videos] {statement}", lim.line_chars))
        if not lines and not pattern_lines:
            return "", handles
        head = f"Participant {memory.participant}: evidence items from {len(memory.videos)} completed videos."
        if len(shown) < len(episodes):
            head += f" {len(shown)} of {len(episodes)} episodes shown, evenly spaced."
        parts = [head, "Episodes (evidence id, video, time in the video, place: the narrated actions):", *lines]
        if pattern_lines:
            parts += ["Consolidated patterns (evidence id [kind, support] statement):", *pattern_lines]
        return "\n".join(parts), handles

    def skills_task(self) -> str:
        lim = self.limits
        return (f"Task (prompt {PROMPT_VERSIONS['skills']}): routine skills. Group the episodes that reach the same goal "
                f"into at most {lim.max_skills} routine skills this person repeats. For each give "
                '{"goal": short verb phrase, "activity_type": one of ' + ", ".join(ACTIVITY_TYPES) + ", "
                f'"canonical_steps": [at most {lim.steps_per_skill} short steps in order], "key_objects": [object names], '
                '"supporting_evidence_ids": [the evidence ids it rests on], "confidence": 0-1}. '
                'Answer {"routine_skills": [...]}; the list may be empty.')

    def preferences_task(self, participant: str) -> str:
        lim = self.limits
        return (f"Task (prompt {PROMPT_VERSIONS['preferences']}): generated preferences. participant: {participant}; "
                f"max_skills: {lim.max_preferences}; allowed_subtypes: {', '.join(ALLOWED_SUBTYPES)}. "
                "Write the person's preferences as reusable skill memories (which tool for which action, where things "
                "go, what they do in which order, which ingredients), each "
                '{"subtype": one of the allowed subtypes, "preference": the statement, "keywords": [words a planner '
                'would search for], "objects": [object names], "context": when it applies, "confidence": 0-1, '
                '"evidence_summary": short, "supporting_evidence_ids": [evidence ids]}. '
                'Answer {"generated_preferences": [...]}; the list may be empty.')

    def enrich(self, memory: ParticipantMemory, consolidation: Consolidation) -> Enrichment:
        out = Enrichment(participant=memory.participant)
        evidence, handles = self.evidence(memory, consolidation)
        if not evidence:
            return out
        names = EntityNames(memory.steps)
        p = memory.participant
        skills = self._ask(p, "routine skills", "skills", "", f"{evidence}\n\n{self.skills_task()}", ENRICHMENT_SYSTEM,
                           SkillsReply)
        if skills is not None:
            out.routine_skills = [self._skill(it, handles, names) for it in skills.routine_skills[: self.limits.max_skills]]
        prefs = self._ask(p, "generated preferences", "preferences", "", f"{evidence}\n\n{self.preferences_task(p)}",
                          ENRICHMENT_SYSTEM, PreferencesReply)
        if prefs is not None:
            out.generated_preferences = [self._preference(it, handles, names)
                                         for it in prefs.generated_preferences[: self.limits.max_preferences]]
        return out

    @staticmethod
    def _cited(refs: list[str], handles: Handles) -> tuple[list[_Evidence], list[str]]:
        items, raw = resolve_refs(refs, handles, _Evidence)
        return items, uniq(raw)

    def _skill(self, it: SkillItem, handles: Handles, names: EntityNames) -> RoutineSkill:
        items, raw = self._cited(it.supporting_evidence_ids, handles)
        episodes = [i.episode for i in items if i.episode is not None]
        first = [e.segments[0] for e in episodes] + [s for i in items if i.episode is None for s in i.segments]
        steps = [clip_text(s, 80) for s in it.canonical_steps][: self.limits.steps_per_skill]
        return RoutineSkill(
            goal=it.goal, activity_type=normalized_activity(it.activity_type, steps), canonical_steps=steps,
            key_objects=it.key_objects, supporting_episodes=uniq(first + raw),
            segments=uniq([s for i in items for s in i.segments] + raw), episodes=episodes, count=max(len(items), 1),
            confidence=it.confidence, entities=names.entities(it.key_objects),
            videos=merge_videos(i.videos for i in items))

    def _preference(self, it: PreferenceItem, handles: Handles, names: EntityNames) -> GeneratedPreference:
        items, raw = self._cited(it.supporting_evidence_ids, handles)
        subtype = it.subtype.strip().lower()
        return GeneratedPreference(
            subtype=subtype if subtype in ALLOWED_SUBTYPES else "other", preference=it.preference,
            keywords=uniq(k.lower() for k in it.keywords)[:12], objects=it.objects, context=it.context,
            count=max(len(items), 1), confidence=it.confidence,
            evidence_summary=it.evidence_summary or f"{len(items)} evidence item(s)",
            supporting_evidence_ids=uniq([s for i in items for s in i.segments] + raw),
            entities=names.entities(it.objects), videos=merge_videos(i.videos for i in items))

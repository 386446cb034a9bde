"""Offline consolidation by a model: one call per completed video (its objects and activity log,
segments under handles S1, S2, ...), then one across videos (the per-video findings under
handles F1, F2, ...)."""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass
from typing import Any

from memora_graph.consolidate import vocab
from memora_graph.consolidate.llm.handles import Handles, EntityNames, resolve_refs, segment_refs
from memora_graph.consolidate.llm.model_step import ModelStep
from memora_graph.consolidate.llm.prompts import (
    EMPTY_SUMMARIES, CONSOLIDATION_SYSTEM, PROMPT_VERSIONS, action_text, clip_text, short_number, evenly_sampled,
)
from memora_graph.consolidate.llm.replies import ConsolidationReply
from memora_graph.consolidate.llm.reply_records import merge_videos, preposition_for, reply_records, Support
from memora_graph.consolidate.memory import ParticipantMemory, MemoryStep, display
from memora_graph.consolidate.records import Consolidation, VideoConsolidation
from memora_graph.text import uniq


@dataclass
class _Finding:
    kind: str  # storage | habit | workflow | sequence
    video: str
    record: Any

    @property
    def segments(self) -> list[str]:
        return list(self.record.segments) if self.kind == "sequence" else list(self.record.supporting_episodes)


class LLMConsolidator(ModelStep):
    """Offline consolidation by a model: one call per completed video, then one across videos."""

    role = "consolidation"

    # -- per video ---------------------------------------------------------------------------
    def video_prompt(self, memory: ParticipantMemory, video: str) -> tuple[str, Handles]:
        """The user message for one video and its segment handles ("", empty handles: no evidence)."""
        lim = self.limits
        steps = memory.steps_by_video().get(video, [])
        by_segment: dict[str, list[MemoryStep]] = defaultdict(list)
        for s in steps:
            by_segment[s.segment].append(s)
        segments = [g for g in memory.segments if g["video"] == video
                    and (by_segment.get(g["id"]) or (g.get("summary") or "").strip().lower() not in EMPTY_SUMMARIES)]
        handles = Handles("S")
        if not segments:
            return "", handles
        shown = evenly_sampled(segments, lim.segments_per_video)
        log_lines = []
        for g in shown:
            acts = by_segment.get(g["id"], [])
            t0 = g.get("t_start", acts[0].t if acts else 0.0)
            t1 = g.get("t_end", acts[-1].t if acts else t0)
            place = g.get("location") or (acts[0].location if acts else "")
            what = "; ".join(action_text(s) for s in acts) if acts else g.get("summary", "")
            log_lines.append(clip_text(f"{handles.add(g['id'])} {short_number(t0)}-{short_number(t1)} s @{place}: {what}", lim.line_chars))

        objects: dict[str, dict] = {}
        for s in steps:
            for i, o in enumerate(s.objects):
                rec = objects.setdefault(o.kind, {"category": o.category, "fixture": o.is_fixture, "n": 0,
                                                  "places": Counter(), "put": Counter()})
                rec["n"] += 1
                if i == 0:
                    rec["places"][s.location] += 1
                    if s.verb in vocab.RELEASING or s.verb == "insert":
                        rec["put"][s.where()[0]] += 1
        ranked = sorted(objects.items(), key=lambda kv: (kv[1]["fixture"], -kv[1]["n"], kv[0]))[: lim.objects_per_video]
        obj_lines = []
        for kind, rec in ranked:
            line = f"- {display(kind)} [{rec['category'] or 'object'}{', fixture' if rec['fixture'] else ''}]: {rec['n']} actions"
            if rec["places"]:
                line += "; at " + ", ".join(p for p, _ in rec["places"].most_common(3) if p)
            if rec["put"]:
                line += "; put " + ", ".join(f"{preposition_for(w)} {w} x{n}" for w, n in rec["put"].most_common(3))
            obj_lines.append(clip_text(line, lim.line_chars))

        head = (f"Participant {memory.participant}, completed video {video}: {len(steps)} narrated actions; "
                f"{len(segments)} segments of 10 s with activity")
        if len(shown) < len(segments):
            head += f"; {len(shown)} segments shown, evenly spaced"
        text = "\n".join([
            head + ".",
            f"Objects ({len(ranked)} of {len(objects)}, most used first):", *obj_lines,
            "Activity log (segment handle, time in the video, place: the narrated actions):", *log_lines,
            "",
            f"Task (prompt {PROMPT_VERSIONS['video']}): consolidate this completed video. Report storage "
            "preferences, organizational habits, workflow patterns and action sequences that this video shows "
            f"(at most {lim.items_per_list} per list, the best supported first). Cite segment handles "
            f"(S1 to S{len(handles)}) in supporting_episodes.",
        ])
        return text, handles

    def consolidate_video(self, memory: ParticipantMemory, video: str) -> VideoConsolidation:
        text, handles = self.video_prompt(memory, video)
        if not text:
            return VideoConsolidation(video=video)
        reply = self._ask(memory.participant, f"video {video}", "video", video, text, CONSOLIDATION_SYSTEM,
                          ConsolidationReply)
        if reply is None:
            return VideoConsolidation(video=video)
        return self._video_records(reply, video, handles, EntityNames(memory.steps_by_video().get(video, [])))

    def _video_records(self, reply: ConsolidationReply, video: str, handles: Handles, names: EntityNames) -> VideoConsolidation:
        def support(refs: list[str]) -> Support:
            segments = segment_refs(refs, handles)
            return Support(segments, segments, [], {video: max(len(segments), 1)}, max(len(segments), 1))

        return VideoConsolidation(video=video, **reply_records(reply, support, names, self.limits))

    # -- across videos -----------------------------------------------------------------------
    def participant_prompt(self, memory: ParticipantMemory, per_video: list[VideoConsolidation]) -> tuple[str, Handles]:
        lim = self.limits
        findings = []
        for v in per_video:
            findings += [_Finding("storage", v.video, r) for r in v.storage_preferences]
            findings += [_Finding("habit", v.video, r) for r in v.organizational_habits]
            findings += [_Finding("workflow", v.video, r) for r in v.workflow_patterns]
            findings += [_Finding("sequence", v.video, r) for r in v.action_sequences]
        handles = Handles("F")
        if not findings:
            return "", handles
        if len(findings) > lim.findings:  # keep the best supported, in their order
            keep = set(sorted(range(len(findings)), key=lambda i: (-findings[i].record.count,
                                                                   -findings[i].record.confidence, i))[: lim.findings])
            findings = [f for i, f in enumerate(findings) if i in keep]
        lines = []
        for f in findings:
            r = f.record
            what = {"storage": lambda: f"{r.statement} [context {r.context}]",
                    "habit": lambda: r.habit,
                    "workflow": lambda: r.pattern,
                    "sequence": lambda: f"{r.title}: {'; '.join(r.steps)}"}[f.kind]()
            kind = "action sequence" if f.kind == "sequence" else f.kind
            lines.append(clip_text(f"{handles.add(f)} {f.video} {kind} ({len(f.segments)} segments, confidence "
                               f"{r.confidence:.2f}): {what}", lim.line_chars))
        videos = [v.video for v in per_video]
        text = "\n".join([
            f"Participant {memory.participant}: findings of the per-video consolidation of {len(videos)} completed "
            f"videos ({', '.join(videos)}).",
            "Findings (handle, video, kind, support: statement):", *lines,
            "",
            f"Task (prompt {PROMPT_VERSIONS['participant']}): consolidate across videos. Merge findings that say the "
            "same thing, keep what recurs across videos or is strongly supported, and state it for this person "
            f"(at most {lim.items_per_list} per list). Cite the finding handles (F1 to F{len(handles)}) it rests on "
            "in supporting_episodes.",
        ])
        return text, handles

    def consolidate_participant(self, memory: ParticipantMemory, per_video: list[VideoConsolidation]) -> Consolidation:
        out = Consolidation(participant=memory.participant, videos=[v.video for v in per_video])
        text, handles = self.participant_prompt(memory, per_video)
        if not text:
            return out
        reply = self._ask(memory.participant, "across videos", "participant", "", text, CONSOLIDATION_SYSTEM,
                          ConsolidationReply)
        if reply is None:
            return out

        def support(refs: list[str]) -> Support:
            """Finding handles -> what the findings rest on; a reference that is no finding of this
            prompt is passed on for the collector to drop."""
            fs, raw = resolve_refs(refs, handles, _Finding)
            return Support(episodes=uniq([x for f in fs for x in f.record.supporting_episodes] + raw),
                            segments=uniq([x for f in fs for x in f.segments] + raw),
                            entities=uniq(e for f in fs for e in f.record.entities),
                            videos=merge_videos(f.record.videos for f in fs),
                            count=max(sum(f.record.count for f in fs), 1))

        return Consolidation(participant=memory.participant, videos=out.videos,
                             **reply_records(reply, support, EntityNames(memory.steps), self.limits))

// description: Every preference (storage, habit, workflow, generated) of a participant.
// params: participant
MATCH (p:Preference)
WHERE p.participant = $participant
RETURN p.id AS id, p.subtype AS subtype, p.statement AS statement, p.keywords AS keywords, p.objects AS objects,
       p.context AS context, p.supporting_episodes AS supporting_episodes, p.source_videos AS source_videos,
       p.count AS count, p.confidence AS confidence, p.retrieval_text AS retrieval_text, p.source AS source,
       p.processor AS processor, p.evidence_summary AS evidence_summary, p.detail AS detail
ORDER BY id

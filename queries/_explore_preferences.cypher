// description: The explorer's preferences: statement, subtype, objects, support.
// params: participant
MATCH (p:Preference)
WHERE p.participant = $participant
RETURN p.id AS id, p.subtype AS subtype, p.source AS source, p.statement AS statement, p.objects AS objects,
       p.context AS context, p.evidence_summary AS evidence, p.count AS count, p.confidence AS confidence,
       p.source_videos AS videos
ORDER BY count DESC, id

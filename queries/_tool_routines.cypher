// description: Every routine (routine skills and recurring action sequences) of a participant.
// params: participant
MATCH (r:Routine)
WHERE r.participant = $participant
RETURN r.id AS id, r.goal AS goal, r.activity_type AS activity_type, r.canonical_steps AS canonical_steps,
       r.key_objects AS key_objects, r.supporting_episodes AS supporting_episodes, r.source_videos AS source_videos,
       r.count AS count, r.confidence AS confidence, r.retrieval_text AS retrieval_text, r.source AS source,
       r.processor AS processor, r.detail AS detail
ORDER BY id

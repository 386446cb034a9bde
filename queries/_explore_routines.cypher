// description: The explorer's routines: goal, steps, key objects, support.
// params: participant
MATCH (r:Routine)
WHERE r.participant = $participant
RETURN r.id AS id, r.source AS source, r.goal AS goal, r.activity_type AS activity_type, r.canonical_steps AS steps,
       r.key_objects AS key_objects, r.count AS count, r.confidence AS confidence, r.source_videos AS videos
ORDER BY count DESC, id

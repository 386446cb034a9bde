// description: A participant's routines (routine skills and recurring action sequences), most supported first (at most 1000 rows).
// params: participant
// example: memora run BANK routines -p participant P03
// bound: limit 1000
MATCH (r:Routine)
WHERE r.participant = $participant
RETURN r.id AS id, r.source AS source, r.goal AS goal, r.activity_type AS activity_type, r.count AS count,
       r.confidence AS confidence, r.source_videos AS videos, r.key_objects AS key_objects
ORDER BY count DESC, id
LIMIT 1000

// description: A participant's preferences (storage, habit, workflow, generated), most supported first (at most 1000 rows).
// params: participant
// example: memora run BANK preferences -p participant P04
// bound: limit 1000
MATCH (p:Preference)
WHERE p.participant = $participant
RETURN p.id AS id, p.subtype AS subtype, p.statement AS statement, p.count AS count, p.confidence AS confidence,
       p.source_videos AS videos, p.keywords AS keywords
ORDER BY count DESC, id
LIMIT 1000

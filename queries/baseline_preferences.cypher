// description: The consolidated preferences of a participant (Graph-2D pattern nodes, planning PrefAdh) (at most 1000 rows).
// params: participant
// example: memora run BANK baseline_preferences -p participant P01
// bound: limit 1000
MATCH (f:Preference)
WHERE f.participant = $participant
OPTIONAL MATCH (f)-[:SUPPORTED_BY]->(s:Segment)
RETURN f.id AS id, f.subtype AS subtype, f.statement AS statement, f.keywords AS keywords, f.objects AS objects,
       f.confidence AS confidence, f.source AS source, collect(s.id) AS segments
ORDER BY id
LIMIT 1000

// description: Every row of `baseline_preferences` (for the code that needs them all; not offered by servers). The consolidated preferences of a participant (Graph-2D pattern nodes, planning PrefAdh).
// params: participant
MATCH (f:Preference)
WHERE f.participant = $participant
OPTIONAL MATCH (f)-[:SUPPORTED_BY]->(s:Segment)
RETURN f.id AS id, f.subtype AS subtype, f.statement AS statement, f.keywords AS keywords, f.objects AS objects,
       f.confidence AS confidence, f.source AS source, collect(s.id) AS segments
ORDER BY id

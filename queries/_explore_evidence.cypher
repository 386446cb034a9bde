// description: Every routine and preference with the segments it cites and the segments it is linked to (SUPPORTED_BY).
// params: participant
// (the explorer reads every record's at once; `inferred_evidence` gives one record's)
MATCH (n:Routine:Preference)
WHERE n.participant = $participant
OPTIONAL MATCH (n)-[:SUPPORTED_BY]->(g:Segment)
WITH n, collect(g.id) AS linked, collect(g.participant) AS linked_participants
RETURN n.id AS id, label(n) AS kind, n.supporting_episodes AS cited, linked, linked_participants
ORDER BY id

// description: One routine or preference (by id: `routines`, `preferences`) with the segments it cites and the segments it is linked to (SUPPORTED_BY).
// params: participant, id
// example: memora run BANK inferred_evidence -p participant P03 -p id P03:routine:4dbd90d58c
// bound: page id
MATCH (n:Routine:Preference {id: $id})
WHERE n.participant = $participant
OPTIONAL MATCH (n)-[:SUPPORTED_BY]->(g:Segment)
WITH n, collect(g.id) AS linked, collect(g.participant) AS linked_participants
RETURN n.id AS id, label(n) AS kind, n.supporting_episodes AS cited, linked, linked_participants
ORDER BY id

// description: Which entities each routine uses and each preference is about (USES / ABOUT edges).
// params: participant
MATCH (n:Routine:Preference)-[:USES|ABOUT]->(e:Entity)
WHERE n.participant = $participant
RETURN n.id AS id, e.id AS entity
ORDER BY id, entity

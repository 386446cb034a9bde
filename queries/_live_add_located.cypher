// description: Current-location edges of entities a remembered moment added or moved (more than a few: one or a few go through _live_located_at, ids bound as scalars; this UNWIND scans the Entity table).
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (e:Entity {id: r.from}), (p:Place {id: r.to})
WHERE e.participant = $participant AND p.participant = $participant
CREATE (e)-[:LOCATED_AT]->(p)
RETURN count(*) AS n

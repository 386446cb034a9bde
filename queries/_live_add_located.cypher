// description: Current-location edges of entities a remembered moment added or moved.
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (e:Entity {id: r.from}), (p:Place {id: r.to})
WHERE e.participant = $participant AND p.participant = $participant
CREATE (e)-[:LOCATED_AT]->(p)
RETURN count(*) AS n

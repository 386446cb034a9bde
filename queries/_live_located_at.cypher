// description: One entity's current-location edge, written by a remembered moment that added or moved it: both ids bound as scalars so Kùzu looks them up in the primary-key index (through UNWIND, _live_add_located scans every entity: ~10 ms of CPU at 1,000 h). Returns the edges written (1, or 0 when the entity or place is missing).
// params: participant, id, place
// mode: write
MATCH (e:Entity {id: $id}), (p:Place {id: $place})
WHERE e.participant = $participant AND p.participant = $participant
CREATE (e)-[:LOCATED_AT]->(p)
RETURN count(*) AS n

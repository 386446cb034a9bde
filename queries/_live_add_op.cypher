// description: One editor operation of a remembered moment, on its entity (bound as a scalar: a primary-key lookup, no scan). Returns the operations written (1, or 0 when the entity is missing).
// params: participant, id, video, turn, t, op, entity, reason, changes, policy
// mode: write
MATCH (e:Entity {id: $entity})
WHERE e.participant = $participant
CREATE (:EditOp {id: $id, participant: $participant, video: $video, turn: $turn, t: $t, op: $op, entity: $entity, reason: $reason, changes: $changes, policy: $policy})-[:EDITED]->(e)
RETURN count(*) AS n

// description: The editor's operations of a remembered moment, each on its entity.
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (e:Entity {id: r.entity})
WHERE e.participant = $participant
CREATE (:EditOp {id: r.id, participant: $participant, video: r.video, turn: r.turn, t: r.t, op: r.op, entity: r.entity, reason: r.reason, changes: r.changes, policy: r.policy})-[:EDITED]->(e)
RETURN count(*) AS n

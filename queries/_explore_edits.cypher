// description: The explorer's editor log: every decision (ADD / UPDATE / DELETE / NOOP) with its object and reason.
// params: participant
MATCH (o:EditOp)-[:EDITED]->(e:Entity)
WHERE o.participant = $participant
RETURN o.video AS video, o.turn AS turn, o.t AS t, o.op AS op, e.id AS entity, o.reason AS reason
ORDER BY video, t, o.id

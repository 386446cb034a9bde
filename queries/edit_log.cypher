// description: The editor's decisions about one object, with their reasons, in order.
// params: participant, object
// example: memora run BANK edit_log -p participant P01 -p object knife
// bound: page object
MATCH (o:EditOp)-[:EDITED]->(e:Entity)
WHERE o.participant = $participant AND (e.object_id = $object OR e.name = $object)
RETURN o.video AS video, o.turn AS turn, o.t AS t, o.op AS op, e.id AS entity, o.reason AS reason
ORDER BY o.video, o.t, o.id

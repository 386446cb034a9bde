// description: The editor's decisions about one object in one video, with their reasons, in order: a video at a time (`videos` lists them).
// params: participant, object, video
// example: memora run BANK edit_log -p participant P01 -p object knife -p video P01_105
// bound: page video
MATCH (e:Entity)<-[:EDITED]-(o:EditOp)
WHERE e.participant = $participant AND (e.object_id = $object OR e.name = $object) AND o.video = $video
RETURN o.video AS video, o.turn AS turn, o.t AS t, o.op AS op, e.id AS entity, o.reason AS reason
ORDER BY o.t, o.id

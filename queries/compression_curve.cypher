// description: One video's segments (a page: `videos` lists them): entity observations (state events) and the editor's ADD / DELETE decisions (the compression curve: records without vs with the editor).
// params: participant, video
// bound: page video
// example: memora run BANK compression_curve -p participant P01 -p video P01_102
MATCH (v:Video {id: $video})-[:HAS_SEGMENT]->(:Segment)<-[:OBSERVED_IN]-(s:StateEvent)
WHERE v.participant = $participant
RETURN s.video AS video, s.turn AS turn, count(*) AS observations, 0 AS adds, 0 AS deletes
UNION ALL
MATCH (o:EditOp)
WHERE o.participant = $participant AND o.video = $video AND o.op IN ['ADD', 'DELETE']
RETURN o.video AS video, o.turn AS turn, 0 AS observations,
       count(CASE WHEN o.op = 'ADD' THEN 1 END) AS adds,
       count(CASE WHEN o.op = 'DELETE' THEN 1 END) AS deletes

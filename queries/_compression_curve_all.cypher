// description: Every row of `compression_curve` (for the code that needs them all; not offered by servers). Per segment: entity observations (state events) and the editor's ADD / DELETE decisions (the compression curve: records without vs with the editor).
// params: participant
MATCH (s:StateEvent)
WHERE s.participant = $participant
RETURN s.video AS video, s.turn AS turn, count(*) AS observations, 0 AS adds, 0 AS deletes
UNION ALL
MATCH (o:EditOp)
WHERE o.participant = $participant AND o.op IN ['ADD', 'DELETE']
RETURN o.video AS video, o.turn AS turn, 0 AS observations,
       count(CASE WHEN o.op = 'ADD' THEN 1 END) AS adds,
       count(CASE WHEN o.op = 'DELETE' THEN 1 END) AS deletes

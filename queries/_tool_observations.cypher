// description: Which entities were observed in which segment and where (the entity-activity graph the tools traverse).
// params: participant
MATCH (s:StateEvent)-[:OBSERVED_IN]->(g:Segment)
WHERE s.participant = $participant AND s.action <> ''
RETURN s.entity AS entity, g.id AS segment, s.location AS location, count(*) AS n

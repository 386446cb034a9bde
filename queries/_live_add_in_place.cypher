// description: Where a remembered moment happened (segment -> places).
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (s:Segment {id: r.from}), (p:Place {id: r.to})
WHERE s.participant = $participant AND p.participant = $participant
CREATE (s)-[:IN_PLACE {op: r.op, is_primary: r.is_primary, zones: r.zones}]->(p)
RETURN count(*) AS n

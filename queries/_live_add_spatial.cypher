// description: Spatial relations between places seen in a remembered moment.
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (a:Place {id: r.from}), (b:Place {id: r.to})
WHERE a.participant = $participant AND b.participant = $participant
CREATE (a)-[:SPATIAL {relation: r.relation, video: r.video, turn: r.turn}]->(b)
RETURN count(*) AS n

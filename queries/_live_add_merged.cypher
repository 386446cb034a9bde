// description: Entities a remembered moment folded into another (duplicate identifications).
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (a:Entity {id: r.from}), (b:Entity {id: r.to})
WHERE a.participant = $participant AND b.participant = $participant
CREATE (a)-[:MERGED_INTO {video: r.video, turn: r.turn}]->(b)
RETURN count(*) AS n

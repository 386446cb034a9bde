// description: The NEXT edge from a video's previous segment to the one just remembered.
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (a:Segment {id: r.from}), (b:Segment {id: r.to})
WHERE a.participant = $participant AND b.participant = $participant
CREATE (a)-[:NEXT]->(b)
RETURN count(*) AS n

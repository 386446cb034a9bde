// description: The NEXT edge from a video's previous segment to the one just remembered.
// params: participant, from_id, to_id
// mode: write
MATCH (a:Segment {id: $from_id}), (b:Segment {id: $to_id})
WHERE a.participant = $participant AND b.participant = $participant
CREATE (a)-[:NEXT]->(b)
RETURN count(*) AS n

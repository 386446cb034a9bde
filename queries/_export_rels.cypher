// description: Every relationship of a participant's memory with its end points, per table and end-point pair (memora export).
// params: participant
MATCH (a)-[r]->(b)
WHERE a.participant = $participant AND b.participant = $participant
RETURN label(r) AS tbl, label(a) AS from_tbl, label(b) AS to_tbl, a.id AS from_id, b.id AS to_id, r AS rel
ORDER BY tbl, from_tbl, to_tbl, from_id, to_id

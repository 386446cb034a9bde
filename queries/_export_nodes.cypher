// description: Every node of a participant's memory, table by table, by id (memora export).
// params: participant
MATCH (n)
WHERE n.participant = $participant
RETURN label(n) AS tbl, n AS node
ORDER BY tbl, n.id

// description: How many editor decisions are stored (to resume numbering).
// params: participant
MATCH (o:EditOp)
WHERE o.participant = $participant
RETURN count(o) AS n

// description: Model calls that failed (after transport retries and the repair turn), with the error (at most 1000 rows).
// params: participant
// example: memora run BANK model_calls_failed -p participant P01
// bound: limit 1000
MATCH (c:ModelCall)
WHERE c.participant = $participant AND NOT c.ok
RETURN c.video AS video, c.turn AS turn, c.segment AS segment, c.role AS role, c.model AS model,
       c.retries AS retries, c.repairs AS repairs, c.error AS error
ORDER BY segment, role
LIMIT 1000

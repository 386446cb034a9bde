// description: Every row of `model_calls_failed` (for the code that needs them all; not offered by servers). Model calls that failed (after transport retries and the repair turn), with the error.
// params: participant
MATCH (c:ModelCall)
WHERE c.participant = $participant AND NOT c.ok
RETURN c.video AS video, c.turn AS turn, c.segment AS segment, c.role AS role, c.model AS model,
       c.retries AS retries, c.repairs AS repairs, c.error AS error
ORDER BY segment, role

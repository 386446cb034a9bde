// description: Model cost and latency per segment (10 s turn): calls, failures, tokens and seconds, per role (at most 1000 rows).
// params: participant
// example: memora run BANK model_calls_by_segment -p participant P01
// bound: limit 1000
MATCH (c:ModelCall)
WHERE c.participant = $participant
WITH c.video AS video, c.turn AS turn, c.segment AS segment, count(*) AS calls,
     count(CASE WHEN NOT c.ok THEN 1 END) AS failed,
     coalesce(sum(c.tokens_in), 0) AS tokens_in, coalesce(sum(c.tokens_out), 0) AS tokens_out,
     sum(c.latency_s) AS latency_s,
     sum(CASE WHEN c.role = 'perception' THEN c.latency_s ELSE 0.0 END) AS perception_s,
     sum(CASE WHEN c.role = 'editor' THEN c.latency_s ELSE 0.0 END) AS editor_s,
     sum(c.retries) AS retries, sum(c.repairs) AS repairs
RETURN video, turn, segment, calls, failed, CAST(tokens_in AS INT64) AS tokens_in,
       CAST(tokens_out AS INT64) AS tokens_out, round(latency_s, 3) AS latency_s,
       round(perception_s, 3) AS perception_s, round(editor_s, 3) AS editor_s,
       CAST(retries AS INT64) AS retries, CAST(repairs AS INT64) AS repairs
ORDER BY segment
LIMIT 1000

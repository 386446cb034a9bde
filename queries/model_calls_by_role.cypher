// description: Model calls per role and model: count, failures, tokens in/out, latency, retries and repairs (at most 100 rows).
// params: participant
// example: memora run BANK model_calls_by_role -p participant P01
// bound: limit 100
MATCH (c:ModelCall)
WHERE c.participant = $participant
RETURN c.role AS role, c.model AS model, count(*) AS calls, count(CASE WHEN NOT c.ok THEN 1 END) AS failed,
       CAST(coalesce(sum(c.tokens_in), 0) AS INT64) AS tokens_in,
       CAST(coalesce(sum(c.tokens_out), 0) AS INT64) AS tokens_out,
       round(sum(c.latency_s), 3) AS latency_total_s, round(avg(c.latency_s), 3) AS latency_mean_s,
       round(max(c.latency_s), 3) AS latency_max_s,
       CAST(sum(c.retries) AS INT64) AS retries, CAST(sum(c.repairs) AS INT64) AS repairs
ORDER BY role, model
LIMIT 100

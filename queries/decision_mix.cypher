// description: The editor's decisions (ADD / UPDATE / DELETE / NOOP) with counts and shares (at most 10 rows).
// params: participant
// example: memora run BANK decision_mix -p participant P01
// bound: limit 10
MATCH (o:EditOp)
WHERE o.participant = $participant
WITH o.op AS op, count(*) AS n
WITH collect({op: op, n: n}) AS rows, sum(n) AS total
UNWIND rows AS r
RETURN r.op AS op, r.n AS n, round(100.0 * r.n / total, 1) AS pct
ORDER BY n DESC
LIMIT 10

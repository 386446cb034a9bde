// description: How many segments a participant's memory holds (the default recipe switches to HNSW above HNSW_MIN_SEGMENTS).
// params: participant
MATCH (s:Segment)
WHERE s.participant = $participant
RETURN count(s) AS n

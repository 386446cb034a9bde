// description: Each video's narrated observations as incremental consolidation marks them (how many, first and last time): a video whose mark moved is read again.
// params: participant
MATCH (s:StateEvent)
WHERE s.participant = $participant AND s.action <> ''
RETURN s.video AS video, count(*) AS n, min(s.t) AS t_min, max(s.t) AS t_max
ORDER BY video

// description: The videos of a participant with their length.
// params: participant
MATCH (v:Video)
WHERE v.participant = $participant
RETURN v.id AS id, v.duration AS duration, v.n_turns AS n_turns
ORDER BY id

// description: The explorer's videos: id, duration and number of 10 s turns.
// params: participant
MATCH (v:Video)
WHERE v.participant = $participant
RETURN v.id AS id, v.duration AS duration, v.n_turns AS turns
ORDER BY id

// description: A video grown by a remembered moment: its length, turns and actions.
// params: participant, video, duration, n_turns, n_actions
// mode: write
MATCH (v:Video {id: $video})
WHERE v.participant = $participant
SET v.duration = $duration, v.n_turns = $n_turns, v.n_actions = $n_actions

// description: Delete a participant's tasks before they are rewritten (with the inferred knowledge).
// params: participant
// mode: write
MATCH (t:Task)
WHERE t.participant = $participant
DELETE t

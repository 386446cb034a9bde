// description: Delete a participant's inferred knowledge (routines, preferences and their edges) before it is rewritten.
// params: participant
// mode: write
MATCH (n:Routine:Preference)
WHERE n.participant = $participant
DETACH DELETE n

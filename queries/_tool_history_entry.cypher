// description: One state-history entry, whole, by its id (looked up by key: a history call reads those it shows).
// params: participant, id
MATCH (s:StateEvent {id: $id})
WHERE s.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state,
       s.location AS location, s.zone AS zone, s.held_by AS held_by, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action, s.narration AS narration, s.op AS op

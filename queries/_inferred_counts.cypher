// description: How many routines and preferences a participant's memory holds.
// params: participant
OPTIONAL MATCH (r:Routine) WHERE r.participant = $participant
WITH count(r) AS routines
OPTIONAL MATCH (f:Preference) WHERE f.participant = $participant
RETURN routines, count(f) AS preferences

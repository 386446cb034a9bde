// description: A remember already acknowledged under this client key (its first answer), if any.
// params: participant, id
MATCH (r:Remembered)
WHERE r.participant = $participant AND r.id = $id
RETURN r.result AS result

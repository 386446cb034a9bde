// description: A remember already acknowledged under this client key (its first answer), if any (the key bound in the pattern: a primary-key lookup).
// params: participant, id
MATCH (r:Remembered {id: $id})
WHERE r.participant = $participant
RETURN r.result AS result

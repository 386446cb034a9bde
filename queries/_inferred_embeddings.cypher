// description: The retrieval texts and embeddings of a participant's stored inferred knowledge (re-runs reuse them).
// params: participant
MATCH (n:Routine:Preference)
WHERE n.participant = $participant
RETURN n.retrieval_text AS text, n.emb AS emb

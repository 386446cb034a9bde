// description: Exact (brute-force) cosine top-50 over place embeddings inside Kùzu.
// params: participant, vector
MATCH (n:Place)
WHERE n.participant = $participant
RETURN n.id AS id, array_cosine_similarity(n.emb, CAST($vector AS FLOAT[384])) AS sim
ORDER BY sim DESC, id
LIMIT 50

// description: A new video of a live memory, under its participant.
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (p:Participant {id: $participant})
CREATE (p)-[:HAS_VIDEO]->(:Video {id: r.id, participant: $participant, duration: r.duration, n_turns: r.n_turns, n_actions: r.n_actions, mode: r.mode, built_at: r.built_at, build_seconds: r.build_seconds})
RETURN count(*) AS n

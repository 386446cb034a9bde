// description: A remembered moment's activity record, in its video (the NEXT edge from the video's previous segment is _live_add_next).
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (v:Video {id: r.video})
WHERE v.participant = $participant
CREATE (v)-[:HAS_SEGMENT]->(:Segment {id: r.id, participant: $participant, video: r.video, turn: r.turn, t_start: r.t_start, t_end: r.t_end, summary: r.summary, narrative: r.narrative, action_breakdown: r.action_breakdown, working_summary: r.working_summary, location: r.location, n_actions: r.n_actions, n_objects: r.n_objects, emb: r.emb})
RETURN count(*) AS n

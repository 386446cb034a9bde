// description: One task as `tasks` returns it (the task a plan starts from; the id bound in the pattern: a primary-key lookup).
// params: participant, id
MATCH (t:Task {id: $id})
WHERE t.participant = $participant
RETURN t.id AS id, t.video AS video, t.goal AS goal, t.family AS family, t.main_object AS main_object,
       t.t_start AS t_start, t.t_end AS t_end, t.objects AS objects, t.tools AS tools, t.places AS places,
       t.segments AS segments, t.stages AS stages, t.steps AS steps

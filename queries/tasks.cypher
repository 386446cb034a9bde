// description: A participant's tasks (task-level memory), in video and time order: goal, stages, steps, objects, tools, places, evidence segments (at most 1000 rows).
// params: participant
// bound: limit 1000
MATCH (t:Task)
WHERE t.participant = $participant
RETURN t.id AS id, t.video AS video, t.goal AS goal, t.family AS family, t.main_object AS main_object,
       t.t_start AS t_start, t.t_end AS t_end, t.objects AS objects, t.tools AS tools, t.places AS places,
       t.segments AS segments, t.stages AS stages, t.steps AS steps
ORDER BY video, t_start, id
LIMIT 1000

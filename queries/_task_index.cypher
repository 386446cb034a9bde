// description: What a planner matches a goal against in each of a participant's tasks (retrieve/tasks.py): goal, family, objects, steps, with the video and start the reader orders them by as `tasks` does (no ORDER BY here: Kùzu's sort held another copy of every step list).
// params: participant
MATCH (t:Task)
WHERE t.participant = $participant
RETURN t.id AS id, t.video AS video, t.t_start AS t_start, t.goal AS goal, t.family AS family, t.objects AS objects,
       t.steps AS steps

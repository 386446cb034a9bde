// description: What a planner matches a goal against in each of a participant's tasks (retrieve/tasks.py), in `tasks`' order: goal, family, objects, steps.
// params: participant
MATCH (t:Task)
WHERE t.participant = $participant
RETURN t.id AS id, t.goal AS goal, t.family AS family, t.objects AS objects, t.steps AS steps
ORDER BY t.video, t.t_start, t.id

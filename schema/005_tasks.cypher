// Task-level memory (written by memora_graph.consolidate with the inferred knowledge): one row per
// task, a stretch of one video's steps that serves one goal (consolidate/tasks.py). The id is
// stable across rebuilds (participant, video, first segment). stages and steps are JSON: the
// step texts per stage (setup / main / finish / cleanup), and each step as (verb, noun, place,
// instrument, stage, t, segment). How recurring tasks are done is written as Routine rows (source
// "task_routine") and Preference rows (source "tasks", subtype = the pattern family).
CREATE NODE TABLE Task(id STRING PRIMARY KEY, participant STRING, video STRING, goal STRING, family STRING, main_object STRING, t_start DOUBLE, t_end DOUBLE, objects STRING[], tools STRING[], places STRING[], segments STRING[], stages STRING, steps STRING);

// description: A remember's acknowledgement under its client key, with its answer.
// params: participant, rows
// mode: write
UNWIND $rows AS r
CREATE (:Remembered {id: r.id, participant: $participant, video: r.video, t: r.t, segment: r.segment, result: r.result, at: r.at})
RETURN count(*) AS n

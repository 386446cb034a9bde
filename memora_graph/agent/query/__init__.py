"""The typed query: what can be asked of a person's memory, read from words or given typed.

    from memora_graph.agent.query import Query, parse, recall, answer_question
    q = parse("How many times did I open the fridge in P06_101?")   # words -> Query
    a = recall(view, "P06", q)                                      # Query -> typed answer
    a = answer_question(view, "P06", "...")                         # both

- `model`: the `Query` (operation, subject, scope, selector, relation) and the typed answer
- `parse`: the compositional parser (scope, relation, selector, operation read independently)
- `lexical`: the question's action and objects as EPIC classes
- `vocabulary`: the person's own words (exact, fuzzy, class)
- `log`: the activity log the answers read
- `answer`: the query compiled onto the stores
"""

from memora_graph.agent.query.answer import answer_question, recall
from memora_graph.agent.query.model import MAX_QUESTION, Action, OpenAnswer, Query, Scope, Subject
from memora_graph.agent.query.parse import QuestionError, parse

__all__ = ["MAX_QUESTION", "Action", "OpenAnswer", "Query", "QuestionError", "Scope", "Subject", "answer_question",
           "parse", "recall"]

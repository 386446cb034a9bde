"""Errors a user sees. Each names what is at fault (file, row, column, bank, query)."""


class MemoraError(Exception):
    """Base class: the CLI turns these into `Error: ...` and exit code 1."""


class DataError(MemoraError):
    """Malformed input data; the message names the file, row and column."""


class StoreError(MemoraError):
    """A Kùzu failure translated into words a user understands."""


class QueryError(MemoraError):
    """A named query that does not exist, or whose parameters do not match."""


class BankError(MemoraError):
    """A bank directory that is missing, damaged or incomplete."""


class ConsolidationError(MemoraError):
    """Offline consolidation produced nothing usable (every model step failed); the participant's
    inferred knowledge is left as it was."""


class QueryRefused(QueryError):
    """An ad-hoc Cypher statement (or a parameter) the read guard will not send to Kùzu: it
    writes, touches files, extensions or other databases, or is not exactly one statement.
    The message names the clause refused and why (memora_graph/cypher_guard.py)."""


class QueryTimeout(StoreError):
    """An ad-hoc query ran past its time limit and was stopped; nothing it did was kept."""


class DiskFullError(StoreError):
    """A write ran out of disk space. The database was not checkpointed and its Kùzu handles were
    abandoned unclosed (closing them after a failed write makes Kùzu 0.11.3 spin in its rollback)."""

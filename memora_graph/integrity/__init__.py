"""Trust the bank: integrity records checked before every open, `memora verify`, `memora forget`.

The records and the checks on open live in `memora_graph.bank` (`Bank.record_integrity`,
`Bank.check`, `Bank.forget`); `files` has what can be checked before Kùzu opens a file, `verify`
the deep report, `cli` the commands.
"""

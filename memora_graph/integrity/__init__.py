"""Trust the bank: integrity records checked before every open, `memora verify`, `memora forget`.

The records and the checks on open live in `memora_graph.bank` (`Bank.record_integrity`,
`Bank.check`, `Bank.forget`), and what can be checked before Kùzu opens a file in
`memora_graph.files` (beside the bank, which needs it); here `verify` has the deep report and `probe`
the child process that opens a database nobody can vouch for; the commands are in
`memora_graph/cli/integrity.py`.
"""

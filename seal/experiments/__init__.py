"""The learning experiments: the instrument that measures transfer, and the learning evidence.

Each module launches ordinary protocol runs as Ray tasks (`launcher`: a private local Ray of
`--jobs` CPUs, or a cluster with `--address`), reads their run directories and reports against a
stated goal: `transfer` (the transfer testbed: its arms, the
ladder of positive controls, seed-paired changes, the MDE and the false-positive rate), `table1`
(paper Table 1 at laptop scale), `kitchen` (single kitchens from their own rewards), `quickstart`
(README command 1 over ten seeds), `reach_sb3` (reach-v3 under seal run and SB3), `mtrl` (SMT
Table 1's learners at laptop scale), `learner` (whether a learner change is no slower on
Meta-World) and `learn` (point and reach-v3 evidence); `until_mde` runs
the testbed's seeds until its MDEs are small enough. The transfer testbed
is split by idea: `arms` (what is compared; `Arm` is every experiment's unit), `launcher` (the runs
as Ray tasks, resume, stopping; every experiment launches through it), `records` (the runs
`--reuse` takes and the code versions and agent keys they were made with), `statistics` (the testbed's costs, paired changes and their CIs, MDEs, AUC, false-positive
rate) and `tables` (its tables and plots), which `transfer` wires to its goals; `ladder` (the
2^3 factorial of what the oracle maps) and `ladder_bench` (`--ladder`) ask which piece carries
transfer. The statistical
methods are `seal.stats`'; the CLI is `seal bench --learn <name>`.
"""

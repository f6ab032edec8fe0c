"""`seal bench`: speed and wall-time measurements, one module per thing measured.

`suite` runs the speed figures of a plain `seal bench` (`run_bench`, `format_table`) from `sb3`
(SAC vs stable-baselines3), `flops` (update FLOP/s vs torch.mm), `collection` (collection
speedups) and `lever` (the ratio lever), all timed with `timing`'s helpers, and `protocol` is the
wall-time projection of `--protocol FILE --epochs N`. The learning experiments that
`seal bench --learn ...` launches live in `seal.experiments`.
"""

"""Layer 4: how a run happens. The set-up pipeline and `Run` (`runner`, `setup`), the epoch loop
(`loop`) and its collaborators (`collection`, `evaluation`, `training`, `stopping`, `loop_log`),
its worker processes (`workers`), checkpoints (`checkpointing`, `checkpoint_fields`), signal
stops (`preemption`, `rollback`), the run directory (`rundir`, `dirlock`), loggers, the phase plan
(`phase_model`) and the memory estimate (`resources`).

What a protocol says (schema, loader, explain) is `seal.protocols`'s: this package imports it,
never the reverse.
"""

"""The task-conditioned learners SMT Table 1 compares beside MTMHSAC, one file each (issue 57):
`paco` (Sun et al. 2022), `soft_modular` (Yang et al. 2020), `moore` (Hendawy et al. 2024) and
`care` (Sodhani et al. 2021), wrapped for the agent by `network.TaskConditionedNetwork`; and
PCGrad's gradient surgery (Yu et al. 2020), `pcgrad`.

Each network class takes (in_dim, out_dim, num_tasks, config: AgentConfig, layer_norm: bool) and
has `reset_parameters(generator, init, head_bound)`, `forward(x (B, in_dim), task_ids (B,)) ->
(B, out_dim)` and `task_parameters()` (the parameters only one task's samples reach).
"""

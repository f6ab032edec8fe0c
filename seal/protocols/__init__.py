"""Layer 4: protocols: what a protocol says. Its TOML schema (`config`), loader and `explain`,
its scheduler table (`scheduling`) and what its evaluation options cost (`evaluation_cost`).
How a run happens (runner, epoch loop, run directory) is `seal.run`'s.

Python API (used by `seal run` and by the Ray sweep):

    config = load_protocol("protocols/quickstart.toml", overrides=["protocol.seeds=1"], scale=0.1)
    result = run_seed(config, seed=0, group_dir=Path("reports/quickstart/my-group"))
    result.run_dir, result.update_counts, result.final_success
"""

from __future__ import annotations

from seal.protocols.config import ProtocolConfig
from seal.protocols.explain import explain
from seal.protocols.loader import config_to_dict, load_protocol
from seal.protocols.toml_io import dumps_toml

__all__ = [
    "ProtocolConfig",
    "RunResult",
    "config_to_dict",
    "dumps_toml",
    "explain",
    "load_protocol",
    "run_seed",
]


def __getattr__(name: str):  # noqa: ANN202 - lazy: the runner imports torch and the learner
    # Deprecated here: import these from seal.run.runner (kept for users' `seal.protocols.run_seed`).
    if name in (
        "RunResult",
        "run_seed",
        "new_group_dir",
        "resume_run",
        "load_policy",
    ):
        from seal.run import runner

        return getattr(runner, name)
    raise AttributeError(name)

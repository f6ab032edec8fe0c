"""Seconds per evaluation of the quickstart protocol, with an evaluation after every epoch.

    python scripts/evaluation_seconds.py [EPOCHS]   # default 5

Runs EPOCHS epochs of protocols/quickstart.toml (no warm-up, an evaluation after every epoch,
a checkpoint every 2) into a temporary directory and prints each evaluation's wall and
main-process CPU seconds, then the mean wall seconds of all but the first (which also builds
the evaluation envs). Used to compare evaluation back ends on one machine, run after run.
"""

import sys
import tempfile
import time
from pathlib import Path

import seal.run.loop as phase
from seal.protocols import load_protocol
from seal.run.runner import run_seed

epochs = int(sys.argv[1]) if len(sys.argv) > 1 else 5
times: list[tuple[float, float]] = []
evaluate = phase.PhaseLoop.evaluate


def timed(self: phase.PhaseLoop) -> None:
    wall, cpu = time.perf_counter(), time.process_time()
    evaluate(self)
    times.append((time.perf_counter() - wall, time.process_time() - cpu))


phase.PhaseLoop.evaluate = timed  # type: ignore[method-assign]
config = load_protocol(
    "protocols/quickstart.toml",
    [
        f"protocol.epochs={epochs}",
        "protocol.seeds=1",
        "training.warmup_steps=0",
        "evaluation.every_grad_steps=0",
        "evaluation.interval=1",
        "checkpoint.interval=2",
        "logging.tensorboard=false",
    ],
)
with tempfile.TemporaryDirectory() as tmp:
    run_seed(config, config.seeds[0], Path(tmp) / "quickstart", quiet=True)
print("evaluations, wall/main-process CPU s:", " ".join(f"{w:.2f}/{c:.2f}" for w, c in times))
later = [w for w, _ in times[1:]]
print(f"mean wall s of evaluations 2..{len(times)}: {sum(later) / max(len(later), 1):.2f}")
print("load average:", " ".join(Path("/proc/loadavg").read_text().split()[:3]))

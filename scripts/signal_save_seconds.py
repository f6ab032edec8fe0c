"""Seconds a run needs to save on SIGTERM with a full replay: the grace period to ask a cluster for.

    python scripts/signal_save_seconds.py [PROTOCOL] [--dir DIR] [--repeats N] [--set K=V ...]

Builds PROTOCOL's first phase (default protocols/high_fk.toml: MT10 and the ten kitchen tasks,
1,000,000 transitions per env) into a temporary run directory under DIR (default: the working
directory's disk), fills its replay to capacity with random transitions, then times, on that
disk, what a run does at a signal (`seal.run.preemption`):

- the epoch mark the loop keeps at every epoch's start (`Stopping.take_mark`, seal.run.stopping), a per-epoch cost;
- the save after a finished epoch (`Stopping.save_for_stop`: the epoch checkpoint, replay
  included, written atomically and fsynced);
- the save after a rollback (`Stopping.roll_back`: the same, from the epoch start's mark).

Prints each figure, the checkpoint's size, and the grace period to request: twice
checkpoint.signal_budget_s plus the slowest save (a 2x margin).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from seal.protocols import load_protocol
from seal.run.loop import PhaseLoop
from seal.run.preemption import Preempted
from seal.run.runner import build
from seal.run.setup import check_resources, plan_run


def fill(loop: PhaseLoop, seed: int = 0) -> int:
    """Fill every task's ring to capacity with random floats; the bytes of the replay."""
    gen = torch.Generator().manual_seed(seed)
    replay, total = loop.replay, 0
    for env, store in replay.storage.items():
        for tensor in store.values():
            tensor.copy_(torch.randn(tensor.shape, generator=gen))
            total += tensor.numel() * tensor.element_size()
        cap = replay.capacity_per_task[env]
        replay.size[env][:] = cap
        replay.position[env][:] = np.arange(len(replay.size[env])) % cap
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("protocol", nargs="?", default="protocols/high_fk.toml")
    parser.add_argument("--dir", default=".", help="where the temporary run directory goes")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="K=V")
    args = parser.parse_args()
    sets = ["protocol.device=cpu", "logging.tensorboard=false", *args.overrides]
    config = load_protocol(args.protocol, sets)
    with tempfile.TemporaryDirectory(dir=args.dir, prefix=".signal-save-") as tmp:
        plan = plan_run(config, 0)
        run = build(plan, check_resources(plan), Path(tmp) / "g" / "seed-0")
        loop = PhaseLoop(run, run.phases[0], None, [run.checkpointer], run.stop)
        stopping = loop.stopping
        nbytes = fill(loop)
        print(f"{args.protocol}: replay {nbytes / 1e9:.2f} GB filled to capacity (", end="")
        print(
            ", ".join(f"{e}: {c:,} per task" for e, c in loop.replay.capacity_per_task.items()),
            end="",
        )
        nets = (loop.agent.actor, loop.agent.critic)
        print(f"); agent {sum(p.numel() for n in nets for p in n.parameters()):,} parameters")
        marks, finished, rolled, sizes = [], [], [], []
        for i in range(args.repeats):
            loop.stop.signum = 15  # as the handler records a SIGTERM
            loop.state.epoch, stopping.saved_epoch = 2 * i + 1, None
            since = time.perf_counter()
            stopping.mark = stopping.take_mark()
            marks.append(time.perf_counter() - since)
            since = time.perf_counter()
            stopping.save_for_stop()
            finished.append(time.perf_counter() - since)
            sizes.append(run.rundir.latest_checkpoint().stat().st_size)  # type: ignore[union-attr]
            loop.state.epoch += 1  # the epoch under way, rolled back to the mark
            loop.stop.rollback_reason, stopping.saved_epoch = "measured", None
            since = time.perf_counter()
            with contextlib.suppress(Preempted):  # what a rollback ends with
                stopping.roll_back()
            rolled.append(time.perf_counter() - since)
            stopping.rolled_back = None
            loop.stop.signum = None
        run.lock.release()
    budget = config.checkpoint.signal_budget_s
    slowest = max(finished + rolled)
    print(f"checkpoint: {max(sizes) / 1e9:.2f} GB on {os.path.realpath(args.dir)}")
    print("epoch mark s: " + " ".join(f"{s:.2f}" for s in marks))
    print("save after a finished epoch s: " + " ".join(f"{s:.1f}" for s in finished))
    print("save after a rollback s: " + " ".join(f"{s:.1f}" for s in rolled))
    grace = 2 * (budget + slowest)
    print(
        f"grace period to request (2 x (checkpoint.signal_budget_s = {budget:g} + slowest save "
        f"{slowest:.1f} s)): {grace:.0f} s"
    )
    print("load average:", " ".join(Path("/proc/loadavg").read_text().split()[:3]))


if __name__ == "__main__":
    main()

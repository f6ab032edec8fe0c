"""Where one update's CPU time goes: torch.profiler over `--updates` updates of each protocol's
agent, on random batches of the protocol's shapes, on one thread.

    python scripts/update_profile.py protocols/mtrl_learn/*.toml [--updates 40] [--top 3]

Prints a line a protocol: the milliseconds an update spends in ops, the matmuls' share (bmm,
baddbmm, addmm, mm) and the next `--top` ops by their share. The profiler's times are wall time inside
each op, so an op the scheduler paused looks longer: on a busy machine profile more updates and
read the shares, not the milliseconds (time speed with `seal bench`, as a ratio).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

MATMULS = frozenset({"aten::bmm", "aten::baddbmm", "aten::addmm", "aten::mm"})


def profile_update(protocol: Path, updates: int) -> dict[str, Any]:
    """{"ms": ms an update in ops, "shares": {op: its share of them, its children excluded}} of
    the protocol's agent, after 3 updates that build its lazy state."""
    from torch.profiler import ProfilerActivity, profile

    from seal.bench.flops import _agent_batches, quickstart_setup
    from seal.device import torch_threads
    from seal.learner import Agent

    specs, agent_config, per_task = quickstart_setup(protocol, device="cpu")  # the CPU update
    agent = Agent(specs, agent_config, seed=0)
    batches = _agent_batches(specs, per_task, seed=0)
    with torch_threads(1):
        for _ in range(3):
            agent.update(batches)
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(updates):
                agent.update(batches)
    times = {e.key: float(e.self_cpu_time_total) for e in prof.key_averages()}
    total = sum(times.values())
    return {"ms": total / updates / 1e3, "shares": {k: v / total for k, v in times.items()}}


def format_profile(name: str, profiled: dict[str, Any], top: int) -> str:
    """One line: ms an update, the matmuls' share, the next `top` ops."""
    shares = profiled["shares"]
    matmul = sum(v for k, v in shares.items() if k in MATMULS)
    rest = sorted((k for k in shares if k not in MATMULS), key=lambda k: -shares[k])[:top]
    others = ", ".join(f"{k.removeprefix('aten::')} {100 * shares[k]:.1f}%" for k in rest)
    return f"{name}: {profiled['ms']:.1f} ms an update in ops, matmuls {100 * matmul:.1f}%; next: {others}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("protocols", nargs="+", type=Path, metavar="PROTOCOL")
    parser.add_argument("--updates", type=int, default=40, help="updates profiled (default 40)")
    parser.add_argument("--top", type=int, default=3, help="ops named after the matmuls")
    args = parser.parse_args(argv)
    if args.updates < 1 or args.top < 0:
        parser.error(f"--updates must be >= 1 and --top >= 0, got {args.updates} and {args.top}")
    from seal.errors import SealError

    for path in args.protocols:
        try:
            print(
                format_profile(path.stem, profile_update(path, args.updates), args.top), flush=True
            )
        except SealError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

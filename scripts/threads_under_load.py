"""The quickstart's update rate at N torch threads, alone or beside a competing process.

    python scripts/threads_under_load.py [--load none|busy|seal] [--threads 1 2 auto] [--repeats 2]
                                         [--epochs 3] [--env OMP_WAIT_POLICY=passive ...]
    python scripts/threads_under_load.py --update protocols/P.toml [--set K=V] [--threads 1 2]
                                         [--seconds 15] [--load ...]

Each trial runs `seal bench --protocol protocols/quickstart.toml --epochs E --set
protocol.threads=N` (threads in turn, REPEATS rounds) and prints its updates/s beside what else
used the machine meanwhile: the cores busy with other processes (from /proc/stat, less the
bench's own CPU time), the bench's kernel share of its CPU time and its involuntary context
switches. `--update P` times only P's update on random batches of its shape, each trial in a
fresh process. `--load` starts a competitor for the whole measurement: `busy` is one Python busy
loop (one core's worth of work), `seal` a second `seal run` of the quickstart at 1 thread (two
seeds side by side). `--env` sets variables for the measured process only, e.g.
OMP_WAIT_POLICY=passive (libgomp's threads sleep at a barrier instead of spinning). The figures
and their load are in docs/benchmarks.md, "Threads under load".
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RATE = re.compile(r"update ([0-9.]+) s per epoch \((\d+) gradient steps, ([0-9.]+) updates/s\)")
TICK = os.sysconf("SC_CLK_TCK")


def busy_jiffies() -> int:
    """Jiffies all CPUs spent busy since boot (everything but idle and iowait)."""
    fields = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return sum(fields) - fields[3] - fields[4]


def competitor(load: str, out: Path) -> subprocess.Popen | None:
    """The competing process for `load`, started (None for `none`)."""
    if load == "none":
        return None
    if load == "busy":
        command = [sys.executable, "-c", "while True: pass"]
    else:
        seal = Path(sys.executable).with_name("seal")
        command = [str(seal), "run", str(ROOT / "protocols" / "quickstart.toml"), "--quiet"]
        command += ["--no-report", "--out", str(out), "--set", "protocol.threads=1"]
    return subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def trial(threads: str, epochs: int, env: dict[str, str]) -> str:
    """One bench at `threads` (a number or "auto"), with what else ran meanwhile, as one line."""
    seal = Path(sys.executable).with_name("seal")
    command = [str(seal), "bench", "--protocol", str(ROOT / "protocols" / "quickstart.toml")]
    setting = threads if threads.isdigit() else f'"{threads}"'
    command += ["--epochs", str(epochs), "--set", f"protocol.threads={setting}"]
    before_children = resource.getrusage(resource.RUSAGE_CHILDREN)
    busy_before, started = busy_jiffies(), time.monotonic()
    done = subprocess.run(command, capture_output=True, text=True, env={**os.environ, **env})
    wall = time.monotonic() - started
    busy = (busy_jiffies() - busy_before) / TICK
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    user = after.ru_utime - before_children.ru_utime
    system = after.ru_stime - before_children.ru_stime
    switches = after.ru_nivcsw - before_children.ru_nivcsw
    match = RATE.search(done.stdout + done.stderr)
    rate = f"{float(match.group(3)):6.1f} updates/s" if match else "no rate (failed?)"
    chosen = re.search(r"update threads: (\d+)", done.stdout)
    if chosen and not threads.isdigit():
        rate += f" (on {chosen.group(1)})"
    others = max(0.0, busy - user - system) / wall
    extra = " ".join(f"{k}={v}" for k, v in env.items())
    return (
        f"threads={threads} {extra:<24} {rate}  other processes {others:.2f} cores; "
        f"bench CPU {user + system:.0f} s ({system / max(user + system, 1e-9):.0%} kernel), "
        f"{switches} involuntary switches, {wall:.0f} s wall"
    )


def update_rate(protocol: str, overrides: list[str], threads: int, seconds: float) -> str:
    """Updates/s of the protocol's agent on random batches of its shape, in this process: the
    update alone (no collection), counted over `seconds` after three untimed updates."""
    import torch

    from seal.bench.flops import _agent_batches
    from seal.learner import Agent, EnvSpec
    from seal.protocols import load_protocol
    from seal.run.phase_model import build_adapters

    config = load_protocol(protocol, overrides)
    adapters = build_adapters(config)
    specs = [EnvSpec(n, a.obs_dim, a.act_dim, len(a.tasks)) for n, a in adapters.items()]
    per_task = int(config.training.batch_per_task)
    torch.set_num_threads(threads)
    agent = Agent(specs, config.agent, seed=0)
    batches = _agent_batches(specs, per_task, 0, "cpu")
    for _ in range(3):
        agent.update(batches)
    parameters = sum(p.numel() for p in agent.actor.parameters())
    parameters += sum(p.numel() for p in agent.critic.parameters())
    batch = per_task * sum(s.num_tasks for s in specs)
    done, started = 0, time.monotonic()
    while time.monotonic() - started < seconds:
        agent.update_on_device(batches)
        done += 1
    rate = done / (time.monotonic() - started)
    return f"{rate:.2f} updates/s ({parameters:,} parameters, batch {batch})"


def update_trial(
    protocol: str,
    overrides: list[str],
    threads: int,
    seconds: float,
    env: dict[str, str],
) -> str:
    """`update_rate` in a fresh process (its own OpenMP pool and environment), with the load."""
    command = [sys.executable, __file__, "--child", protocol, "--threads", str(threads)]
    command += ["--seconds", str(seconds), *(a for o in overrides for a in ("--set", o))]
    busy_before, started = busy_jiffies(), time.monotonic()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(
        command,
        capture_output=True,
        text=True,
        env={**os.environ, **env},
    )
    wall = time.monotonic() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    own = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    others = max(0.0, (busy_jiffies() - busy_before) / TICK - own) / wall
    result = done.stdout.strip().splitlines()[-1] if done.returncode == 0 else done.stderr[-300:]
    extra = " ".join(f"{k}={v}" for k, v in env.items())
    return f"threads={threads} {extra:<24} {result}; other processes {others:.2f} cores"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--load", choices=("none", "busy", "seal"), default="none")
    parser.add_argument("--threads", nargs="+", default=["1", "2"], help='numbers or "auto"')
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--env", nargs="*", default=[], metavar="NAME=VALUE")
    parser.add_argument(
        "--update",
        metavar="PROTOCOL",
        help="time only this protocol's update on random batches, not `seal bench --protocol`",
    )
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--child", metavar="PROTOCOL", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(update_rate(args.child, args.overrides, int(args.threads[0]), args.seconds))
        return
    env = dict(item.split("=", 1) for item in args.env)
    with tempfile.TemporaryDirectory(prefix="seal-threads-") as out:
        rival = competitor(args.load, Path(out))
        try:
            if rival is not None:
                time.sleep(20)  # past the competitor's start-up (imports, demonstrations)
            print(f"load: {args.load}; {os.cpu_count()} CPUs; loadavg {os.getloadavg()}")
            if args.update:
                print(f"{args.update} {' '.join(args.overrides)}")
            for _ in range(args.repeats):
                for threads in args.threads:
                    if args.update:
                        line = update_trial(
                            args.update, args.overrides, int(threads), args.seconds, env
                        )
                    else:
                        line = trial(threads, args.epochs, env)
                    print(line, flush=True)
        finally:
            if rival is not None:
                # SIGTERM, so that a seal run ends its collection workers too (under SIGKILL a
                # forked worker of one outlived it).
                rival.terminate()
                try:
                    rival.wait(timeout=60)
                except subprocess.TimeoutExpired:
                    rival.kill()
                    rival.wait()


if __name__ == "__main__":
    main()

"""The protocol TOML schema: frozen, keyword-only dataclasses whose fields carry docstrings.

A protocol file has one table per dataclass below (`[protocol]`, `[envs.<name>]`, `[agent]`,
`[replay]`, `[training]`, `[evaluation]`, `[scheduler]`, `[finetune]`, `[checkpoint]`,
`[transfer]`, `[logging]`, and the pass-through tables `[search]` and `[resources]`). Loading validates every
key and value and raises `ConfigError` naming the file, `table.key`, the bad value and what is
valid, before anything is written (`seal.typed_config.build`: pydantic, with each field's bounds
in its annotation). Defaults are the paper-scale values of issue 4.

`[agent]` is validated against `seal.learner.AgentConfig` and `[scheduler]` against the scheduler
configs of `seal.schedulers`, so those layers own their own fields and docs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import Field, with_config

from seal.errors import SealError
from seal.typed_config import SCHEMA

if TYPE_CHECKING:  # the learner (and torch) load only when an agent is built
    from seal.envs.base import EnvAdapter
    from seal.learner.collection import Collector
    from seal.learner.config import AgentConfig, EnvSpec
    from seal.learner.replay import MultiTaskReplay
    from seal.schedulers.base import SchedulerConfig

Kind = Literal["baseline", "finetune", "joint"]


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class ProtocolTable:
    """[protocol]: what is run and how often."""

    name: str = ""
    """Protocol name: the folder under the reports root (default: the file's stem)."""
    kind: Kind = "baseline"
    """baseline (MTMHSAC on one env), finetune (pre-train on A, fine-tune on B) or joint (SEAL on all envs)."""
    description: str = ""
    """One line saying what the protocol is for."""
    column: str = ""
    """The report column a baseline or joint protocol's runs form, e.g. "PaCo" (default: from its kind and scheduler, e.g. "Single Env" for a baseline); finetune protocols keep their two phase columns."""
    seeds: Annotated[int, Field(ge=1)] = 2
    """Number of seeds, run one after another into one group (Appendix B: 2)."""
    first_seed: Annotated[int, Field(ge=0)] = 0
    """Seeds are first_seed, first_seed + 1, ..., first_seed + seeds - 1."""
    epochs: Annotated[int, Field(ge=1)] = 10_000
    """Epochs per phase (Appendix D: 10,000). An epoch collects one episode per task, then trains."""
    device: str = "auto"
    """Torch device: "auto" (CUDA if present, else CPU), "cpu", "cuda", "cuda:1", ..."""
    threads: Annotated[int, Field(ge=0)] | Literal["auto"] = "auto"
    """torch intra-op threads for the updates: "auto" (seal.device.update_threads, on parameters x batch and usable cores), N (at most the usable cores) or 0 (torch's default); acting uses one."""
    matmul_precision: Literal["highest", "high"] = "highest"
    """float32 matmuls on CUDA: "highest" (full float32) or "high" (TF32 tensor cores, JAX's default for float32 on such GPUs; 1.47x the paper-scale update on an H200, docs/benchmarks.md). CPU runs ignore it."""


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class EnvConfig:
    """[envs.<name>]: one environment; <name> is how the run's tables and files refer to it."""

    adapter: str = ""
    """Built-in adapter name (metaworld, franka_kitchen_dense, point, point_view, point_diagonal) or "package.module:Class" (default: <name>)."""
    tasks: tuple[str, ...] = ()
    """Task names or set names (e.g. "mt10"); empty means all of the adapter's tasks."""
    episode_length: Annotated[int, Field(ge=0)] = 0
    """Steps per episode (truncation); 0 means the adapter's default (Meta-World 500, kitchen 280)."""
    options: dict[str, Any] = field(default_factory=dict)
    """Adapter options, validated by the adapter, e.g. { gravity_compensation = true } for the kitchen."""
    demo_episodes: Annotated[int, Field(ge=0)] | None = None
    """This env's scripted-expert episodes per task in the replay; unset = `training.demo_episodes`.

    E.g. demonstrations for the kitchen only, so a Meta-World task's learning is not mostly its
    expert's (protocols/table1_small).
    """


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class ReplayConfig:
    """[replay]: the per-(env, task) replay buffers."""

    capacity_per_env: Annotated[int, Field(ge=1)] = 1_000_000
    """Transitions kept per environment, split evenly over its tasks (Meta-World: 1e6)."""

    def build(self, specs: Sequence[EnvSpec], *, device: str, seed: int) -> MultiTaskReplay:
        """The replay over `specs` (one buffer per task of each env) on `device`, sampled by `seed`."""
        from seal.learner.replay import MultiTaskReplay

        return MultiTaskReplay(specs, self.capacity_per_env, device=device, seed=seed)


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class TrainingConfig:
    """[training]: the epoch loop (garage MTSAC convention)."""

    warmup_steps: Annotated[int, Field(ge=0)] = 4_000
    """Env steps per environment with uniform random actions before the first gradient update."""
    batch_per_task: Annotated[int, Field(ge=1)] = 128
    """Transitions per task in one update at uniform composition (MT10: 10 x 128 = 1280)."""
    grad_steps_per_epoch: Annotated[int, Field(ge=-1)] = -1
    """Gradient steps after each epoch's collection; -1 = as many as the env steps of one collected episode.

    With environments of different episode lengths, -1 means the longest episode among the
    environments that collected this epoch (e.g. 500 when Meta-World and the kitchen both
    collect), so no environment's episode contributes more env steps than there are updates.
    """
    collector: Literal["auto", "sync", "subproc-batched", "inline-batched", "gym-async"] = "auto"
    """Collection backend (seal.learner.env_backends.BACKENDS): "auto" measures one step and picks "inline-batched" or "sync"."""
    demo_episodes: Annotated[int, Field(ge=0)] = 0
    """Episodes per task of the adapter's scripted expert put in the replay at the start of each phase (0 = none).

    Demonstrations are data: their env steps count neither toward `warmup_steps` (the random
    warm-up still runs in full, so a run with demos differs from one without only by the demos)
    nor toward the env-step counts, and they count as consumed updates only when sampled.
    """

    overlap: bool = False
    """Collect beside the updates (actor-learner): each epoch's episodes are collected in a worker process with the policy as it was before the epoch's updates, while those updates train on the replay up to the previous epoch's episodes.

    Against the paper's serial loop (collect, then update on what was just collected) the policy
    that collects lags one epoch, and the updates start one epoch later (the first epoch after
    the warm-up has nothing collected before it to train on). Each epoch takes as many gradient
    steps as the episodes it trains on (`grad_steps_per_epoch`). Deterministic and resumable
    exactly like the serial loop (the worker's instances are seeded as the loop's, its action
    noise from (seed, phase, epoch)), but not the same run: off (the paper's loop) by default.
    """

    def build_collector(
        self,
        adapters: Mapping[str, EnvAdapter],
        seed: int,
        replicas: int = 1,
        backend: str | None = None,
    ) -> Collector:
        """The env instances of `adapters` on this config's collection backend (or `backend`, e.g.
        the one "auto" resolved to before), seeded by `seed` (`replicas` per task: evaluation)."""
        from seal.learner.collection import Collector

        return Collector(adapters, seed=seed, backend=backend or self.collector, replicas=replicas)


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class EvaluationConfig:
    """[evaluation]: Appendix B's evaluation procedure."""

    interval: Annotated[int, Field(ge=1)] = 100
    """Evaluate every this many epochs (and after the last epoch); unused when every_grad_steps > 0."""
    every_grad_steps: Annotated[int, Field(ge=0)] = 0
    """Evaluate whenever the phase's gradient steps reach a multiple of this (mid-epoch), and after the last epoch; 0 = use `interval`.

    The update-count metric can only be as fine as the evaluations: at 128 samples per task,
    K = 16,667 gives the paper's grid of ~2.133 M (6.4 M / 3), which no whole number of 500-step
    epochs gives (a choice; see docs/hyperparameters.md for its evaluation cost).
    """
    episodes: Annotated[int, Field(ge=1)] = 50
    """Deterministic episodes per task per evaluation (paper: 100; 50 halves the cost)."""
    threshold: Annotated[float, Field(ge=0.0, le=1.0)] = 0.9
    """Success rate at which a task counts as learned for the update-count metric."""
    stop_when_reached: bool = False
    """End each phase at the first evaluation at which every task has reached `threshold` (its update count is then fixed); for learning checks."""
    decide_early: bool = False
    """Stop a task's evaluation once its episodes so far settle whether it reaches `threshold` (at 50 episodes and 0.9: 45 successes, or 6 failures); the verdict is the full evaluation's, exactly.

    Episodes run in their fixed order (episode k of a task is the same episode whether or not
    other tasks stopped), in waves of the evaluation's parallel instances; the verdict is checked
    after each wave by `seal.evaluation.reaches`, the update-count metric's own rule. A task
    stopped early records its success and return over its episodes up to the one that settled
    it (the rest of that wave is not counted, so the numbers do not depend on the machine's
    cores), and train.csv records `eval_episodes/<task>` (those counted) and
    `eval_decided_early/<task>` for every evaluation that may stop early. Such rates are not the full evaluation's (45/45 reads 1.0, 0/6 reads 0.0): `seal
    report`'s success curves leave those evaluations out, best.pt is chosen among the evaluations
    that ran every episode, and a phase whose evaluations steer training (a scheduler that reads
    them, curriculum_v2; the pre-training whose best.pt starts fine-tuning) runs all episodes.
    Off by default until measured (issue 60).
    """
    full_every: Annotated[int, Field(ge=1)] = 10
    """With decide_early: every this-many-th evaluation of a phase, and its last epoch's, runs all episodes (1 = all do).

    10 keeps a full-precision point every 10 evaluations (about 30 points on a paper-scale curve
    at every_grad_steps = 16667) while at most a tenth of the evaluations pay the full cost.
    """
    end_on_success: bool = False
    """End an evaluation episode at its first success; its return is then the sum of rewards up to and including that step (not the full episode's).

    Success rates are unchanged (an episode succeeds if it succeeds at any step). Returns in
    metrics.csv are cut returns, shorter and not comparable with runs that had it off; config.toml
    records the choice. The critic probe bootstraps a cut episode as it does one cut at the time
    limit: `earned` adds gamma^T Q(s_T, pi(s_T)) at the success step T.
    """
    mode: Literal["sync", "async"] = "sync"
    """"sync": evaluate with training stopped, as the paper's loop; "async": a worker process evaluates a snapshot while training goes on (the same rows, written when they come back).

    sync is the default because it is the paper's loop and needs no second process (a spawned
    worker with its own agent and evaluation instances per phase); async wrote the same rows and
    ran the quickstart faster even on 2 cores (docs/benchmarks.md), so long runs should turn it
    on. Asynchronous evaluation uses the same deterministic policy, seeded
    episodes and consumed-update counts, so the rows are those of a synchronous evaluation of the
    same snapshot; a scheduler that reads evaluations (the curricula) gets each before its next
    plan. With `stop_when_reached` the phase ends at the first epoch end after the deciding
    result comes back, so it trains a little longer than a synchronous run (its rows and update
    counts are the same).

    The paper's criterion, the first evaluation at >= `threshold`, keeps its meaning: a row
    carries the snapshot's gradient steps, env steps and consumed updates, and a first crossing
    records the snapshot's updates, never those made while it was evaluated, so the update count
    is the one a synchronous run of the same snapshots records. `seal run`'s time line then
    counts as evaluation only the loop's waiting on it, the worker's CPU seconds apart.
    """


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class FinetuneConfig:
    """[finetune]: pre-train on `source`, fine-tune on `target` (kind = "finetune" only)."""

    source: str = ""
    """The [envs.<name>] pre-trained on (phase "pretrain")."""
    target: str = ""
    """The [envs.<name>] fine-tuned on (phase "finetune")."""
    pretrain_epochs: Annotated[int, Field(ge=0)] = 0
    """Epochs of pre-training; 0 means [protocol].epochs."""
    finetune_epochs: Annotated[int, Field(ge=0)] = 0
    """Epochs of fine-tuning; 0 means [protocol].epochs."""
    lr_factor: Annotated[float, Field(gt=0.0)] = 1.0
    """Learning-rate multiplier while fine-tuning; 1.0 because Appendix D trains all parameters as before."""
    reinit_critic: bool = False
    """Also re-initialise the critic (Appendix D keeps it)."""
    alignment: dict[str, str] = field(default_factory=dict)
    """The aligned one-hot table in place of the paper's Table 3 (default, when empty): task (or "adapter:task") -> a group name; tasks of one group share an id, unlisted tasks get their own. An entry whose group no other task joins is warned of (a typo of a shared group, most likely)."""


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class TransferConfig:
    """[transfer]: start a baseline or joint run from another run's checkpoint (issue 5, e.g. MT1 -> MT3).

    The new agent is built as usual, then takes every parameter of the checkpoint's agent except
    the policy's last layer; one-hot columns of tasks the source did not have start at zero.
    """

    checkpoint: str = ""
    """A checkpoint written by `seal run` (e.g. reports/<protocol>/<group>/seed-0/checkpoints/best.pt), relative to the working directory."""
    lr_factor: Annotated[float, Field(gt=0.0)] = 0.1
    """Actor and critic learning rates are multiplied by this after the transfer (issue 5: 0.1)."""
    reinit_critic: bool = False
    """Keep the fresh critic instead of the transferred one."""
    # The maps are properties of the envs, not of SEAL: seal.envs registers them by name, a protocol names one.
    map: str = ""
    """A correspondence known by construction (seal.envs.env_map: "testbed_oracle", or "package.module:NAME") through which the env of the map's target adapter also starts from the checkpoint's env of its source adapter (a positive control's oracle, docs/transfer_testbed.md); "" = none."""
    map_modules: str | tuple[Any, ...] = "all"
    """With map: the target env's pieces that are mapped, a list from "translator", "head", "critic", "temperature" that holds "translator" (seal.pieces); "all" = all four, "translator" = ["translator"]; the pieces not mapped keep their fresh init."""
    map_unmapped_log_std: Annotated[float, Field(ge=-20.0, le=2.0)] = -20.0
    """With map and the head mapped: the log std of the target's action entries that no source entry drives (the testbed's distractors), in [-20, 2]; -20 (the lower clamp) = no noise; -1.354 = expected log-density 0, so they add nothing to the mapped critic's soft Bellman target (docs/transfer_testbed.md, round 5)."""

    def __post_init__(self) -> None:
        from seal.pieces import map_pieces

        map_pieces(self.map_modules)  # a bad set fails at load, naming the valid ones
        if self.map:
            from seal.envs import env_map

            try:
                env_map(self.map)  # an unknown name fails at load, naming the valid ones
            except SealError as exc:
                raise SealError(f"map: {exc}") from None

    @property
    def pieces(self) -> tuple[str, ...]:
        """The pieces `map_modules` maps, in `seal.pieces.PIECES` order."""
        from seal.pieces import map_pieces

        return map_pieces(self.map_modules)


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class CheckpointConfig:
    """[checkpoint]: what is saved for resume and for `seal eval`."""

    interval: Annotated[int, Field(ge=1)] = 100
    """Save a checkpoint every this many epochs (and after the last)."""
    keep_last: Annotated[int, Field(ge=1)] = 2
    """Keep the last K epoch checkpoints (ckpt-<epoch>.pt); best.pt is kept besides."""
    save_replay: bool = True
    """Store the replay in epoch checkpoints; resume needs it (best.pt never holds it)."""
    on_signal: bool = True
    """On SIGTERM or SIGINT, stop at a safe point: save the last finished epoch's checkpoint, print it with the --resume command, exit 143 or 130 (docs/faults.md). Keeps a CPU copy of the agent's state from every epoch's start. Turn it off where something else owns the signals (a debugger; a harness that stops and checkpoints the run itself) or where that copy does not fit in host memory."""
    signal_budget_s: Annotated[float, Field(ge=0.0)] = 10.0
    """After a signal, finish the epoch under way if its remaining work fits in this many seconds, else roll back to its start. Ask the cluster for a grace period of 2 x (this + the save's seconds); docs/faults.md measures the save."""


@with_config(SCHEMA)
@dataclass(frozen=True, kw_only=True)
class LoggingConfig:
    """[logging]: training-curve logs (train.csv; mirrored to TensorBoard and, optionally, wandb)."""

    train_interval: Annotated[int, Field(ge=1)] = 10
    """Log losses, mean Q and temperatures every this many epochs."""
    tensorboard: bool = True
    """Also write TensorBoard events under tb/<phase>/ (one TensorBoard run per phase)."""
    wandb: Literal["off", "offline", "online"] = "off"
    """Also log the same scalars to Weights & Biases under wandb/: "offline" never touches the network (`wandb sync` uploads later), "online" uploads as it runs; needs the extra: pip install -e ".[wandb]"."""
    drift: bool = False
    """At every evaluation, log each env's translator, head, critic and temperatures' distance from the phase's start, ||W - W0|| / ||W0|| over the piece's parameters concatenated (train.csv key drift/<piece>; seal.learner.drift); keeps W0 on the agent's device and in epoch checkpoints."""


@dataclass(frozen=True, kw_only=True)
class ProtocolConfig:
    """A fully resolved protocol: everything a run needs, with the file it came from."""

    path: str = "<memory>"
    """The protocol file (for error messages and provenance)."""
    protocol: ProtocolTable
    envs: dict[str, EnvConfig]
    agent: AgentConfig
    """The resolved [agent] table."""
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    training: TrainingConfig = field(default_factory=TrainingConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    scheduler: SchedulerConfig | None = None
    """The [scheduler] table's config (seal.schedulers); None: every task collects, uniform batch."""
    finetune: FinetuneConfig | None = None
    transfer: TransferConfig | None = None
    """[transfer] if given (baseline and joint only)."""
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)
    search: dict[str, Any] = field(default_factory=dict)
    """[search]: passed through to `seal sweep`."""
    resources: dict[str, Any] = field(default_factory=dict)
    """[resources]: passed through to `seal sweep`."""

    @property
    def name(self) -> str:
        """The protocol's name."""
        return self.protocol.name

    @property
    def kind(self) -> str:
        """baseline, finetune or joint."""
        return self.protocol.kind

    @property
    def seeds(self) -> list[int]:
        """The seeds this protocol runs."""
        return list(range(self.protocol.first_seed, self.protocol.first_seed + self.protocol.seeds))

    def demo_episodes(self, env: str) -> int:
        """Scripted-expert episodes per task that env `env` puts in the replay (`EnvConfig.demo_episodes`)."""
        own = self.envs[env].demo_episodes
        return self.training.demo_episodes if own is None else own

    def replace(self, **changes: Any) -> ProtocolConfig:
        """A copy with some top-level fields changed."""
        return dataclasses.replace(self, **changes)


# Tables that map one-to-one onto a dataclass.
SIMPLE_TABLES: dict[str, type] = {
    "protocol": ProtocolTable,
    "replay": ReplayConfig,
    "training": TrainingConfig,
    "evaluation": EvaluationConfig,
    "finetune": FinetuneConfig,
    "checkpoint": CheckpointConfig,
    "logging": LoggingConfig,
}
ALL_TABLES: tuple[str, ...] = (
    "protocol",
    "envs",
    "agent",
    "replay",
    "training",
    "evaluation",
    "scheduler",
    "finetune",
    "transfer",
    "checkpoint",
    "logging",
    "search",
    "resources",
)

"""The Ray side of a sweep: what each trial asks of Ray, and the Ray connection.

`parse_resources` reads the protocol's [resources] table, `RaySession` starts a private local Ray
or joins a cluster (and shuts down only what it started), and `check_address` / `check_feasible`
fail early with a SealError where Ray itself would retry or wait forever. Ray is imported only by
`import_ray`, when a session opens.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any, ClassVar

from seal.errors import SealError
from seal.protocols.config import ProtocolConfig
from seal.sweep import config_tables as sweep_tables
from seal.sweep.config_tables import Resources


def parse_resources(config: ProtocolConfig) -> Resources:
    """The protocol's [resources] table (already checked when it loaded)."""
    return sweep_tables.parse_resources(config.resources, config.path)


class RaySession:
    """`with RaySession(address):` a Ray connection; shut down on exit only if this opened it.

    address None starts a private local Ray in this process's machine (address="local", never an
    unrelated cluster found through RAY_ADDRESS); "auto" or "HOST:PORT" joins an existing cluster.
    If Ray is already initialised (e.g. by a test fixture or a notebook), that session is used;
    with `strict`, only if it is the one asked for (`_check_same`), else SealError.
    """

    opened: ClassVar[tuple[str | None, int | None] | None] = None
    """(address, num_cpus) of the Ray a RaySession started in this process, while it runs."""

    def __init__(
        self, address: str | None = None, num_cpus: int | None = None, *, strict: bool = False
    ) -> None:
        self.address = address
        self.num_cpus = num_cpus
        self.strict = strict
        self.started = False

    def __enter__(self) -> ModuleType:
        ray = import_ray()
        if ray.is_initialized():
            if self.strict:
                self._check_same(ray)
            return ray
        kwargs: dict[str, Any] = {
            "include_dashboard": False,
            "log_to_driver": False,
            "logging_level": "warning",
        }
        if self.address is None:
            # Ray counts the machine's CPUs itself (cgroup limits included) unless told otherwise.
            kwargs.update(address="local", **({"num_cpus": self.num_cpus} if self.num_cpus else {}))
            # Trials at the priority of the sweep that started them, as `seal run` is: Ray's default
            # worker niceness, 15, starves them beside any other busy process (a test search of 16 s
            # alone was still running after 8 min beside two learning runs on 2 cores; 23 s at 0).
            kwargs["_system_config"] = {"worker_niceness": 0}
        else:
            # "auto" is resolved here, not by Ray: Ray's own "auto" falls back to any Ray process
            # it finds on the machine, such as the private Ray of a running `seal bench --learn`.
            kwargs["address"] = _auto_address() if self.address == "auto" else self.address
            if kwargs["address"] is None:
                raise SealError(_NO_AUTO)
        try:
            ray.init(**kwargs)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            where = (
                "a local Ray"
                if self.address is None
                else f"the Ray cluster at --address {self.address}"
            )
            hint = (
                ""
                if self.address is None
                else " (start it with `ray start --head` on the head node, or drop --address for a local Ray; "
                "if the cluster uses token authentication, set RAY_AUTH_MODE=token and RAY_AUTH_TOKEN to the "
                "token `ray get-auth-token` prints on the head node)"
            )
            raise SealError(f"cannot start or join {where}: {exc}{hint}") from None
        self.started = True
        RaySession.opened = (self.address, self.num_cpus)
        return ray

    def _check_same(self, ray: ModuleType) -> None:
        """SealError unless the Ray already initialised here is the one asked for: a RaySession's
        of the same address and CPUs, or the cluster whose GCS is at the HOST:PORT asked for. A
        command that means a private local Ray must not run on a cluster a notebook joined, nor
        one asked to join a cluster on a local Ray."""
        if RaySession.opened == (self.address, self.num_cpus):
            return
        gcs = ray.get_runtime_context().gcs_address
        if self.address == gcs:
            return
        # "auto" names the cluster this machine joins: the one a notebook's ray.init("auto")
        # joined, never a private local Ray a RaySession started here.
        if self.address == "auto" and RaySession.opened is None and _auto_address() == gcs:
            return

        def cpus(n: int | None) -> str:
            return "every CPU" if n is None else f"{n} CPUs"

        opened = RaySession.opened
        if opened is not None and opened[0] is None:
            have = f"a local Ray with {cpus(opened[1])}, started here"
        else:
            have = f"the Ray whose GCS is at {gcs}"
        if self.address is None:
            want = f"a private local Ray with {cpus(self.num_cpus)}"
        else:
            want = f"the Ray cluster at --address {self.address}"
        raise SealError(
            f"Ray is already initialised in this process ({have}), not as asked ({want}); "
            "ask for that one, or call ray.shutdown() first"
        )

    def __exit__(self, *exc: object) -> None:
        if self.started:
            import_ray().shutdown()
            RaySession.opened = None


def _auto_address() -> str | None:
    """The address --address auto joins (`_auto_source`'s), or None."""
    found = _auto_source()
    return None if found is None else found[0]


def _auto_source() -> tuple[str, str] | None:
    """(address, where it came from) that --address auto joins: RAY_ADDRESS, else the cluster the
    last `ray start` on this machine left (Ray's record of it), else None. Unlike Ray's own
    "auto" it never falls back to any Ray process running here: those include the private Rays
    of other seal commands. HOST:PORT is canonicalised as Ray does (localhost -> this node's IP),
    so that it compares equal to a joined cluster's GCS address."""
    import os

    env = os.environ.get("RAY_ADDRESS", "")
    try:
        from ray._private import services
    except ImportError:
        services = None  # type: ignore[assignment]
    if env not in ("", "auto", "local"):  # "local" would start a Ray, not join one
        found = (env, f"RAY_ADDRESS={env}")
    else:
        try:
            started = services.find_bootstrap_address(None) if services else None
        except Exception:  # noqa: BLE001 - a private API that may move: then only RAY_ADDRESS counts
            started = None
        if started is None:
            return None
        found = (started, "the cluster `ray start` last left on this machine")
    if services is not None and "://" not in found[0]:
        try:
            return services.canonicalize_bootstrap_address(found[0]), found[1]
        except Exception:  # noqa: BLE001 - a malformed address is reported by check_address
            pass
    return found


_NO_AUTO = (
    "--address auto: no Ray cluster to join: RAY_ADDRESS names none and no `ray start` left one on "
    "this machine (a private Ray that another seal command started is never joined); start one "
    "with `ray start --head`, give --address HOST:PORT, or drop --address to use a local Ray"
)


def alive_cpu_nodes(ray: ModuleType) -> list[dict[str, Any]]:
    """The alive nodes of the Ray cluster with at least one CPU (`ray.nodes()`'s entries)."""
    return [n for n in ray.nodes() if n.get("Alive") and n["Resources"].get("CPU", 0) >= 1]


def check_feasible(ray: ModuleType, config: ProtocolConfig, res: Resources) -> None:
    """SealError when no node could ever hold one trial (Ray would otherwise wait forever)."""
    total = ray.cluster_resources()
    for key, name, asked in (("CPU", "cpus", res.cpus), ("GPU", "gpus", res.gpus)):
        have = float(total.get(key, 0.0))
        if asked > have:
            raise SealError(
                f"{config.path}: resources.{name} = {asked:g} per trial, but the Ray cluster has {have:g} {key}s in all; "
                f"lower resources.{name}, start the local Ray with more (--num-cpus), or join a bigger cluster (--address)"
            )


def check_address(address: str | None, timeout_s: float = 5.0) -> None:
    """SealError unless something listens at a HOST:PORT --address (Ray itself would retry for minutes).

    "auto" must resolve to a cluster (`_auto_address`), which is then checked; None (local
    Ray), "local" and "ray://" client addresses are left to Ray.
    """
    if address == "auto":
        found = _auto_source()
        if found is None:
            raise SealError(_NO_AUTO)
        if "://" not in found[0]:
            try:
                check_address(found[0], timeout_s)
            except SealError as exc:
                raise SealError(f"--address auto, from {found[1]}: {exc}") from None
        return
    if address is None or address == "local" or "://" in address:
        return
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise SealError(
            f"--address {address!r}: expected auto or HOST:PORT, e.g. 10.0.0.1:6379 (the address `ray start --head` printed)"
        )
    import socket

    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise SealError(
            f"--address {address}: no Ray cluster answers there ({exc.strerror or exc}); start one with "
            f"`ray start --head --port={port}` on that node, or drop --address to use a local Ray"
        ) from None


def import_ray(command: str = "seal sweep") -> ModuleType:
    """The `ray` module, or SealError saying that `command` needs it and how to install it."""
    try:
        import ray
    except ImportError:
        raise SealError(
            f"{command} needs Ray: pip install 'seal[ray]' (or pip install 'ray[tune]')"
        ) from None
    return ray

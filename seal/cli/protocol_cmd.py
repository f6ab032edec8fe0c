"""`seal protocol explain FILE [--set TABLE.KEY=VALUE] [--scale F]`: the resolved protocol with its docs."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `seal protocol explain` and `seal protocol check`."""
    from seal.cli.run_cmd import add_protocol_arguments

    p = subparsers.add_parser("protocol", help="inspect protocol files", description=__doc__)
    sub = p.add_subparsers(dest="protocol_command", metavar="SUBCOMMAND", required=True)
    explain = sub.add_parser(
        "explain",
        help="print every resolved value with its documentation",
        description="Print the resolved protocol (every key, defaults included) with each key's "
        "documentation, then the networks, the estimated memory and the update threads it would "
        "use (or, with --toml, the resolved TOML alone).",
    )
    add_protocol_arguments(explain)
    explain.add_argument(
        "--toml",
        action="store_true",
        help="print the resolved config as TOML (what a run saves as config.toml)",
    )
    explain.set_defaults(func=run_explain)
    check = sub.add_parser(
        "check",
        help="validate a protocol file; exit 2 with the offending key if it is invalid",
        description="Validate a protocol file as `seal run` would load it, and run what `seal run` "
        "checks before it writes anything ([transfer]'s checkpoint, the memory estimate on the "
        "protocol's device when this machine has it): print one ok line (its name, kind and envs) "
        "and exit 0, or one line naming the file, the key, the value and what is valid, and exit 2.",
    )
    add_protocol_arguments(check)
    check.set_defaults(func=run_check)


def run_explain(args: argparse.Namespace) -> int:
    """Print the resolved config (docs or TOML)."""
    from seal.protocols import config_to_dict, dumps_toml, explain, load_protocol

    config = load_protocol(args.file, args.overrides, args.scale)
    print(dumps_toml(config_to_dict(config)) if args.toml else explain(config), end="")
    if not args.toml:
        from seal.provenance import resolve_device
        from seal.run.phase_model import build_adapters
        from seal.run.resources import choose_update_threads, estimate_resources

        device = resolve_device(config.protocol.device)
        estimate = estimate_resources(config, build_adapters(config), device)
        print(f"# networks: {estimate.describe_networks(config.agent.architecture)}")
        print(f"# estimated memory: {estimate.describe()}")
        print(f"# update threads: {choose_update_threads(config, estimate).describe()}")
    return 0


def run_check(args: argparse.Namespace) -> int:
    """Validate only."""
    from seal.device import resolve_device
    from seal.errors import SealError
    from seal.protocols import load_protocol
    from seal.run.setup import check_resources, check_transfer, plan_run, transfer_source

    config = load_protocol(args.file, args.overrides, args.scale)
    try:
        resolve_device(config.protocol.device)
    except SealError as exc:  # a GPU protocol checked on a CPU node: its memory is the GPU's
        memory, plan = f"; memory not checked: {exc}", plan_run(config, device="cpu")
    else:
        memory, plan = "", plan_run(config)
    state = transfer_source(config)  # a checkpoint that is missing or does not fit fails here
    if state is not None:
        check_transfer(plan, state)
    if not memory:
        check_resources(plan)  # what `seal run` refuses before it writes anything
    print(
        f"{args.file}: ok (protocol {config.name!r}, kind {config.kind}, envs {', '.join(config.envs)})"
        f"{memory}"
    )
    return 0

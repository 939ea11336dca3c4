"""Command line: `python -m clrender [COMMAND] ...`.

With no command it lists the OpenCL platforms and devices and runs a self-check kernel on
the selected device. Errors the user can fix print as one line (no traceback unless --debug)
and exit with status 2.
"""

from __future__ import annotations

import argparse
import sys

import pyopencl as cl

from clrender.errors import ClrenderError
from clrender.runtime import create_runtime, describe_device, list_devices


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m clrender", description=__doc__.split("\n")[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    commands = parser.add_subparsers(dest="command")
    devices = commands.add_parser("devices", help="list OpenCL devices and run a self-check")
    add_device_option(devices)
    return parser


def add_device_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", default=None,
                        help="OpenCL device: index in the list, or a name substring "
                             "(default: PYOPENCL_CTX, else the first device)")  # fmt: skip


def command_devices(args: argparse.Namespace) -> int:
    from clrender.selfcheck import run_self_check

    devices = list_devices()
    print("OpenCL devices:")
    for index, device in enumerate(devices):
        print(f"  [{index}] {describe_device(device)}, "
              f"{device.max_compute_units} compute units")  # fmt: skip
    runtime = create_runtime(args.device)
    print(f"selected: {runtime.describe()}")
    ok, message = run_self_check(runtime)
    print(f"self-check: {message}: {'ok' if ok else 'FAILED'}")
    return 0 if ok else 1


COMMANDS = {"devices": command_devices, None: command_devices}


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        args.device = None
    try:
        return COMMANDS[args.command](args)
    except (ClrenderError, cl.Error) as err:
        if args.debug:
            raise
        print(f"clrender: error: {err}", file=sys.stderr)
        return 2

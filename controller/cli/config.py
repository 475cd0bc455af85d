"""``config check FILE`` and ``config show [FILE]``: the leg's TOML configuration.

``check`` exits 0 with a one-line summary, or 2 with every problem on its own line (each naming
the dotted field, the value found, and what is allowed with its unit). ``show`` prints the
effective configuration, the file's with every default for what it leaves out, as TOML that
reads back to the same configuration.
"""

from __future__ import annotations

import argparse
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="config_command", required=True, metavar="check|show")
    check = sub.add_parser("check", help="validate FILE: exit 0 and a summary, or 2 and every problem")
    check.add_argument("file", metavar="FILE", help="a TOML configuration, e.g. configs/odrive-leg.toml")
    show = sub.add_parser("show", help="print the effective configuration (FILE's, with every default) as TOML")
    show.add_argument("file", metavar="FILE", nargs="?", default=None, help="a TOML configuration (default: none)")


def run(args: argparse.Namespace) -> int:
    from controller.settings.file import ConfigError, DeployConfig, load_config, summary, to_toml

    if args.config_command == "show" and args.file is None:
        config, where = DeployConfig(), "the defaults"
    else:
        try:
            config = load_config(args.file)
        except ConfigError as exc:
            for line in exc.lines():
                print(line, file=sys.stderr)
            n = len(exc.problems)
            print(f"config {args.config_command}: {args.file}: {n} problem{'s' if n != 1 else ''}", file=sys.stderr)
            return 2
        where = f"{args.file} with the defaults for what it leaves out"
    if args.config_command == "check":
        print(f"{args.file}: OK: {summary(config)}")
        return 0
    sys.stdout.write(to_toml(config, header=f"elegant-stepping configuration: {where}\n"
                                            "(each comment: what the key is, and what is allowed)"))
    return 0

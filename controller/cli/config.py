"""``config check FILE``, ``config show [FILE]``, ``config confirm FILE --bringup REPORT.json``.

``check`` exits 0 with a one-line summary, or 3 (an invalid input, :mod:`controller.errors`) with
every problem on its own line (each naming the dotted field, the value found, and what is allowed
with its unit) and a last line counting them. A file that cannot be read, is not UTF-8, is not
TOML (the line named) or is nested deeper than any configuration is one problem of the same kind:
exit 3. A valid configuration
whose calibration nobody confirmed still exits 0, with a WARNING line on stderr: the daemon will
not arm it until it is confirmed. ``show`` prints the effective configuration, the file's with
every default for what it leaves out, as TOML that reads back to the same configuration.

``confirm`` is a person's word that the calibration in FILE is this leg's: after
``elegant-stepping-leg bringup --config FILE --json REPORT.json`` passed on the leg, it checks
the report (a bring-up report, passed, moves done, the same axes on the same node ids, written
after FILE last changed) and writes ``[calibration] confirmed = true``, ``confirmed_at`` and
``bringup`` into FILE (:func:`controller.settings.file.confirm_calibration`: FILE.bak first,
then an atomic write). A refusal is exit 3 and one line (``config confirm: refused: ...``): what
is refused is an input, the report or the file, never the person's option syntax; FILE's own
problems are listed as by ``check`` (exit 3), and a FILE that cannot be written (not root) is one
line, exit 3.

Exit codes: 0 done; 2 a malformed command line (argparse); 3 an invalid or unreadable FILE or
report, or a refused confirmation.
"""

from __future__ import annotations

import argparse
import sys

EXIT_OK, EXIT_INPUT = 0, 3  # controller.errors' codes (this module imports nothing at its top)


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="config_command", required=True, metavar="check|show|confirm")
    check = sub.add_parser("check", help="validate FILE: exit 0 and a summary, or 3 and every problem")
    check.add_argument("file", metavar="FILE", help="a TOML configuration, e.g. configs/odrive-leg.toml")
    show = sub.add_parser("show", help="print the effective configuration (FILE's, with every default) as TOML")
    show.add_argument("file", metavar="FILE", nargs="?", default=None, help="a TOML configuration (default: none)")
    confirm = sub.add_parser("confirm", help="confirm FILE's calibration after a bring-up that passed on the leg "
                                             "(writes [calibration] into FILE, FILE.bak kept)")
    confirm.add_argument("file", metavar="FILE", help="the leg's configuration, e.g. /etc/elegant-stepping/leg.toml")
    confirm.add_argument("--bringup", required=True, metavar="REPORT.json",
                         help="the report of `elegant-stepping-leg bringup --config FILE --json REPORT.json`")


def _config_error(exc, verb: str, file: str) -> int:
    for line in exc.lines():
        print(line, file=sys.stderr)
    n = len(exc.problems)
    print(f"config {verb}: {file}: {n} problem{'s' if n != 1 else ''}", file=sys.stderr)
    return EXIT_INPUT


def unconfirmed_warning(file: str) -> str:
    """The WARNING line of ``config check`` for a configuration whose calibration is not confirmed."""
    return (f"WARNING: {file}: calibration not confirmed: the daemon will not arm this leg until it is. On the leg: "
            f"`elegant-stepping-leg bringup --config {file} --json report.json`, then (every item PASS) "
            f"`elegant-stepping-leg config confirm {file} --bringup report.json`")


def _confirm(args: argparse.Namespace) -> int:
    from controller.settings.file import ConfigError, ConfirmRefused, confirm_calibration

    try:
        config, backup, kept = confirm_calibration(args.file, args.bringup)
    except ConfigError as exc:
        return _config_error(exc, "confirm", args.file)
    except ConfirmRefused as exc:
        print(f"config confirm: refused: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except OSError as exc:
        print(f"config confirm: {args.file}: cannot write it: {exc.strerror or exc} (as root: sudo)", file=sys.stderr)
        return EXIT_INPUT
    how = ("the [calibration] lines edited, every comment kept" if kept else
           "rewritten as the full effective configuration: its comments are in the copy only")
    print(f"{args.file}: calibration confirmed at {config.calibration.confirmed_at} on {config.calibration.bringup}")
    print(f"{args.file}: {how}; the file before: {backup}")
    return 0


def run(args: argparse.Namespace) -> int:
    from controller.settings.file import ConfigError, DeployConfig, load_config, summary, to_toml

    if args.config_command == "confirm":
        return _confirm(args)
    if args.config_command == "show" and args.file is None:
        config, where = DeployConfig(), "the defaults"
    else:
        try:
            config = load_config(args.file)
        except ConfigError as exc:
            return _config_error(exc, args.config_command, args.file)
        where = f"{args.file} with the defaults for what it leaves out"
    if args.config_command == "check":
        print(f"{args.file}: OK: {summary(config)}")
        if config.armable_reason() is not None:
            print(unconfirmed_warning(args.file), file=sys.stderr)
        return 0
    sys.stdout.write(to_toml(config, header=f"elegant-stepping configuration: {where}\n"
                                            "(each comment: what the key is, and what is allowed)"))
    return 0

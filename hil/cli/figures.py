"""``figures``: the paper's figures (PNG and SVG) from learn output folders.

Every folder is checked before a figure is drawn: :func:`hil.analysis.metrics.load_run` refuses a
folder without a ``metrics.json`` or with one of the wrong structure or version; what the figures
read beyond that (each trial's footfalls, its trace, the obstacle's size) is checked here
(:func:`check_figure_inputs`). A problem is one line naming the file and the field (exit 3);
``--out`` and ``--json`` that cannot be written are refused first.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from controller.cli.common import write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folders", nargs="+", help="learn output folders (seeds, heights, baselines)")
    p.add_argument("--out", required=True, help="output folder for the figures")
    p.add_argument("--json", default="-", help="where to list the written files (default: stdout)")
    p.add_argument("--compare", metavar="NAME", default=None,
                   help="instead of the paper's figures: one running-success curve per folder, labelled by "
                        "the folder's name (for example a HIL run beside a lockstep run), into NAME.png/.svg")


def _number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _numbers(x: Any) -> bool:
    return isinstance(x, list) and all(_number(v) for v in x)


def check_figure_inputs(run: dict[str, Any], source: str) -> None:
    """Refuse, in one line naming ``source`` and the field, a loaded run whose fields the figures
    read are missing or of the wrong type (a hand-edited or foreign ``metrics.json``).

    Raises:
        InputError: the first such field.
    """
    from controller.errors import InputError

    def bad(field: str, what: str) -> InputError:
        return InputError(f"{source}: {field} {what}; not a learn run's metrics.json as the figures read it")

    config = run.get("config")
    if not isinstance(config, dict):
        raise bad("config", "is not an object")
    if not config.get("obstacle_heights_m") and not _number(config.get("obstacle_height_m")):
        raise bad("config.obstacle_height_m", f"is {config.get('obstacle_height_m')!r}, not a height in metres")
    if not _number(config.get("obstacle_depth_m", 0.1)):
        raise bad("config.obstacle_depth_m", f"is {config.get('obstacle_depth_m')!r}, not a depth in metres")
    trials = run.get("trials")
    if not isinstance(trials, list) or not trials:
        raise bad("trials", "is not a non-empty list")
    for i, t in enumerate(trials):
        where = f"trials[{i}]"
        if not isinstance(t, dict):
            raise bad(where, "is not an object")
        if not isinstance(t.get("success"), (bool, int)):
            raise bad(f"{where}.success", f"is {t.get('success')!r}, not true or false")
        if not _numbers(t.get("footfalls_m")):
            raise bad(f"{where}.footfalls_m", "is not a list of positions in metres")
        if "modulation_s" in t and not _numbers(t["modulation_s"]):
            raise bad(f"{where}.modulation_s", "is not a list of seconds")
        if "trace" in t:
            trace = t["trace"]
            if not isinstance(trace, dict):
                raise bad(f"{where}.trace", "is not an object")
            for key, values in trace.items():
                if not isinstance(values, list) or not all(_number(v) or isinstance(v, bool) or v is None
                                                           for v in values):
                    raise bad(f"{where}.trace.{key}", "is not a list of numbers")
            if not isinstance(t.get("index"), int) or not _number(t.get("obstacle_height_m")):
                raise bad(where, "is traced but lacks its index or obstacle_height_m")


def compare_figure(folders: list[str], out: str, name: str) -> dict[str, list[Path]]:
    """One running-success curve per folder, labelled by the folder's name, into ``name``."""
    from controller.errors import InputError
    from hil.analysis.figures import success_curves
    from hil.analysis.metrics import load_run

    if not name or Path(name).name != name:
        raise InputError(f"--compare {name!r}: give a file name without a folder")
    labels = [Path(f).resolve().name for f in folders]
    if len(set(labels)) != len(labels):
        raise InputError(f"--compare: the folders' names label the curves, and two are the same: {labels}")
    curves = {label: [[bool(t["success"]) for t in load_run(f)["trials"]]] for label, f in zip(labels, folders)}
    success_curves(curves, Path(out), name=name, title="the same seed, run two ways")
    return {name: [Path(out) / f"{name}.png", Path(out) / f"{name}.svg"]}


def run(args: argparse.Namespace) -> int:
    from controller.cli.common import check_output_file, check_output_folder
    from hil.analysis.figures import paper_figures
    from hil.analysis.metrics import load_run

    check_output_folder(args.out, "--out")
    check_output_file(args.json, "--json")
    for folder in args.folders:
        check_figure_inputs(load_run(folder), str(Path(folder) / "metrics.json"))
    if args.compare is not None:
        written = compare_figure(args.folders, args.out, args.compare)
    else:
        written = paper_figures(args.folders, args.out)
    write_json(args.json, {name: [str(p) for p in paths] for name, paths in written.items()})
    print(f"wrote {len(written)} figures (PNG and SVG) into {args.out}", file=sys.stderr)
    return 0

"""Every row of the bad-input table (:mod:`tests.bad_inputs`): no traceback, the documented exit
code, the key words of the one-line message, and nothing the command refused touched.

``python3 -m tests.test_bad_inputs --markdown > docs/errors.md`` runs every row the same way and
writes the table of ``docs/errors.md`` from what the commands actually print.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from tests.bad_inputs import HARNESS, LEG, ROWS, SETUPS, Row, setup_files

ROOT = Path(__file__).resolve().parents[1]
MODULES = {HARNESS: "hil.cli", LEG: "controller.cli"}
TIMEOUT_S = 180.0


def _env() -> dict[str, str]:
    """This checkout first on the path, whatever the editable install points at."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return dict(os.environ, PYTHONPATH=path, PYTHONUNBUFFERED="1")


def _inprocess(row: Row, argv: list[str]) -> tuple[int, str]:
    from controller.cli import main as leg_main
    from hil.cli import main as harness_main

    main = harness_main if row.prog == HARNESS else leg_main
    real = importlib.util.find_spec
    if row.hide:
        importlib.util.find_spec = lambda name, *a: None if name in row.hide else real(name, *a)  # type: ignore
    err, out = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse's usage errors
                code = exc.code if isinstance(exc.code, int) else 1
    finally:
        importlib.util.find_spec = real
    return code, err.getvalue()


def _subprocess(row: Row, argv: list[str]) -> tuple[int, str]:
    if row.how == "script":
        script = shutil.which(row.prog)
        assert script is not None, f"the console script {row.prog} is not installed"
        cmd = [script, *argv]
    else:
        cmd = [sys.executable, "-m", MODULES[row.prog], *argv]
    done = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=TIMEOUT_S,
                          stdin=subprocess.DEVNULL)
    return done.returncode, done.stderr


def _sigint(row: Row, argv: list[str]) -> tuple[int, str]:
    """Start the verb, and send SIGINT as soon as it is importing its simulation (pybullet says so
    on stderr as it loads): the start-up, before any work."""
    proc = subprocess.Popen([sys.executable, "-m", MODULES[row.prog], *argv], cwd=ROOT, env=_env(),
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stderr.readline()  # blocks until pybullet is loaded (or the process ends)
        proc.send_signal(signal.SIGINT)
        rest = proc.stderr.read()
        proc.wait(TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, first + rest


def run_row(row: Row, tmp: Path) -> tuple[int, str]:
    """Run ``row`` with its files in ``tmp``: (exit code, stderr)."""
    argv, _ = row.expand(tmp)
    if row.how == "inprocess":
        return _inprocess(row, argv)
    if row.how in ("subprocess", "script"):
        return _subprocess(row, argv)
    if row.how == "sigint":
        return _sigint(row, argv)
    raise ValueError(f"{row.name}: unknown way to run {row.how!r}")


def message(stderr: str, row: Row) -> str:
    """The line the command answered with: its last line that starts with the program's name (a
    verb that reports a list of problems, ``config check``: its first and its last line)."""
    ours = [line for line in stderr.splitlines() if line.startswith(f"{row.prog} ") or line.startswith(f"{row.prog}:")]
    if ours:
        return ours[-1]
    lines = [line for line in stderr.strip().splitlines() if line.strip()]
    if not lines:
        return ""
    return lines[0] if len(lines) == 1 else f"{lines[0]} ... {lines[-1]}"


def _snapshot(tmp: Path, names: tuple[str, ...]) -> dict[str, bytes | None]:
    return {n: (tmp / n).read_bytes() if (tmp / n).is_file() else None for n in names}


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("bad_inputs")
    setup_files(tmp)
    return tmp


def test_the_table_has_at_least_40_distinct_rows():
    assert len(ROWS) >= 40
    assert len({r.name for r in ROWS}) == len(ROWS)
    assert {r.how for r in ROWS} <= {"inprocess", "subprocess", "script", "sigint"}
    assert {r.code for r in ROWS} >= {0, 2, 3, 4, 6, 130}


@pytest.mark.parametrize("row", ROWS, ids=[r.name for r in ROWS])
def test_bad_input(row: Row, scratch: Path):
    if row.name in SETUPS:
        SETUPS[row.name](scratch)
    before = _snapshot(scratch, row.keep)
    assert all(v is not None for v in before.values()), f"{row.name}: a file to keep is missing before the run"
    code, err = run_row(row, scratch)
    _, words = row.expand(scratch)
    assert "Traceback" not in err, f"{row.name}: a traceback:\n{err}"
    assert code == row.code, f"{row.name}: exit {code}, expected {row.code}:\n{err}"
    line = message(err, row)
    for word in words:
        assert word in err, f"{row.name}: {word!r} not in the message:\n{err}"
    if not row.owner:  # the command-line layer's own rows: the answer is a line of the program's
        assert line.startswith(row.prog), f"{row.name}: no line from {row.prog}:\n{err}"
    assert _snapshot(scratch, row.keep) == before, f"{row.name}: changed or deleted {row.keep}"


def test_docs_errors_md_shows_every_row_as_generated():
    """docs/errors.md is regenerated whenever a row is added or changed (the command at its top)."""
    doc = (ROOT / "docs" / "errors.md").read_text()
    assert "python3 -m tests.test_bad_inputs --markdown > docs/errors.md" in doc
    for i, row in enumerate(ROWS, 1):
        assert f"| {i} | {_cell(row.mistake)} | `{_cell(row.prog)} " in doc, f"row {i} ({row.name}) not in docs/errors.md"
    assert "**(expected exit" not in doc  # generated from a tree where every row held


def test_a_truncated_log_read_with_partial_gives_exactly_the_frames_before_the_damage(scratch):
    """The valid frames are the whole log's first ones, as many as the warning says."""
    from hil.analysis.buslog import LogReading

    whole = list(LogReading(scratch / "whole.blf"))
    reading = LogReading(scratch / "truncated.blf")
    part = list(reading)
    assert reading.damage is not None and reading.damage.frame == len(part) + 1 == 2731
    assert [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in part] == \
        [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in whole[:len(part)]]
    assert reading.check(partial=True) == (f"{scratch / 'truncated.blf'}: read 2730 frames, stopped at frame 2731: "
                                           f"{reading.damage.reason}")


# -- the table as a document ---------------------------------------------------------------------------
EXIT_CODES = (
    (0, "done (and a damaged log read with --partial: the valid frames, one warning line)"),
    (1, "the job ran and its outcome is a failure (a check failed, a cell failed, a fault row)"),
    (2, "usage: an option is missing, malformed or out of range (argparse's own code)"),
    (3, "input: a file or folder is missing, damaged, of the wrong structure or version, or cannot be written; "
        "an invalid configuration"),
    (4, "bus: the CAN bus cannot be opened, or a node on it does not answer"),
    (5, "safety stop: the leg stopped itself (a latched fault, an estop, an axis left closed loop)"),
    (6, "this install lacks what the verb needs (an extra, User-Mode Linux)"),
    (70, "a bug: the one case with a traceback, followed by a line saying it is a bug"),
    (130, "interrupted (SIGINT); what was finished is kept"),
)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def markdown() -> str:
    """``docs/errors.md``: the exit codes and every row as its command prints it now."""
    from controller import errors

    for code, _ in EXIT_CODES:  # the table below and controller.errors agree
        assert code in {v for k, v in vars(errors).items() if k.startswith("EXIT_")}, code
    lines = [
        "# Errors and exit codes",
        "",
        "<!-- Generated: python3 -m tests.test_bad_inputs --markdown > docs/errors.md (do not edit by hand) -->",
        "",
        "Generated by `python3 -m tests.test_bad_inputs --markdown > docs/errors.md`: every command below was run",
        "and its message is copied as printed (`DIR` is the scratch folder of the run). `tests/test_bad_inputs.py`",
        "runs the same rows (`tests/bad_inputs.py`) and asserts for each: no traceback, the exit code, and the key",
        "words of the message.",
        "",
        "Every verb of both command lines (`elegant-stepping`, `elegant-stepping-leg`) answers an expected",
        "failure with one line, `PROG VERB: error: MESSAGE`, naming the option or file and what is wrong, and",
        "one of these exit codes (`controller/errors.py`, mapped in `controller/cli/common.py` `main`):",
        "",
        "| code | meaning |",
        "|---|---|",
        *(f"| {code} | {_cell(text)} |" for code, text in EXIT_CODES),
        "",
        "A damaged bus log (an empty, garbage, truncated or bit-flipped `.blf`, a junk line in a candump `.log`)",
        "is read up to the damage; the message names the frame (BLF) or line (text log) where it starts. Exit 3,",
        "or with `--partial` exit 0 and a warning line saying how many frames were read and where it stopped",
        "(`hil/analysis/buslog.py`, the one reader of `decode`, `replay` and the bus load).",
        "",
        "`firmware-sim --scenario PATH` never deletes a file that is not its own: an existing file that is not a",
        "socket, or a socket another process serves, is refused (exit 3); only a stale socket (nobody answers on",
        "it) is replaced. Its own socket file is removed when it stops.",
        "",
        "## Bad inputs",
        "",
        "| # | mistake | command | exit | message as printed |",
        "|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="es-bad-inputs-") as folder:
        tmp = Path(folder)
        setup_files(tmp)
        for i, row in enumerate(ROWS, 1):
            if row.name in SETUPS:
                SETUPS[row.name](tmp)
            t0 = time.monotonic()
            code, err = run_row(row, tmp)
            print(f"{row.name}: exit {code} ({time.monotonic() - t0:.1f} s)", file=sys.stderr)
            argv, _ = row.expand(tmp)
            shown = " ".join(a if a and " " not in a else repr(a) for a in argv).replace(folder, "DIR")
            how = {"sigint": " (then SIGINT while it starts)", "script": " (the installed console script)"}.get(row.how, "")
            if row.hide:
                how += f" (with {', '.join(row.hide)} not installed)"
            said = message(err, row).replace(folder, "DIR")
            flag = "" if code == row.code and "Traceback" not in err else f" **(expected exit {row.code})**"
            lines.append(f"| {i} | {_cell(row.mistake)} | `{_cell(row.prog + ' ' + shown)}`{how} | {code}{flag} "
                         f"| `{_cell(said)}` |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if sys.argv[1:] != ["--markdown"]:
        print("usage: python3 -m tests.test_bad_inputs --markdown > docs/errors.md", file=sys.stderr)
        sys.exit(2)
    sys.stdout.write(markdown())

"""``bench --profile DIR``: where the time of a learning run goes, per layer of the stack.

A short learning run in lockstep (:class:`hil.experiments.learn.LearningRun`, bring-up included:
the same code path as ``learn``) runs under :mod:`cProfile` (standard library; no sampling profiler
is needed). The modules it imports are imported before the profiler starts, so start-up is not in
the table. Each function's *self time* (time in its own code, not in what it calls) is then given
to one layer of the stack:

Rules, in order:
  1. A function belongs to the first layer of :data:`LAYERS` one of whose ``prefixes`` is its
     qualified name (``module.function``) or a dotted ancestor of it. The module of a Python
     function is the one imported from its file (``sys.modules``); that of a builtin is in its
     name, as cProfile gives it (``<built-in method pybullet.stepSimulation>`` is
     ``pybullet.stepSimulation``, ``<method 'copy' of 'numpy.ndarray' objects>`` is ``numpy.ndarray.copy``).
     So ``pybullet.stepSimulation`` is its own layer and every other pybullet builtin (joint
     states, contacts, rays, motor commands) is "other PyBullet calls"; the controller's range
     filter module is listed before ``controller`` and so is not counted as the controller tick.
  2. A function of the standard library or a builtin of no listed package (``copy.deepcopy``,
     ``queue.Queue.put``, ``time.time``, ``struct`` packing, ``len``, a dataclass's generated
     ``__init__``) is not a layer of its own: its self time goes to the layers of its callers, each
     caller's share being the self time cProfile recorded on that call edge. A caller that is
     itself of the standard library passes its share on to its own callers in proportion to
     their cumulative time on each edge, and so on up the chain (a call cycle inside the standard
     library is cut where it closes). The reason: python-can's cost *is* its deepcopy, its queue
     and its clock reads, the frame codec's is its ``struct`` calls, and a table that put them
     under "other" would hide exactly what one would change.
  3. Anything else (another third-party package such as scipy or bitstruct, a chain of standard
     library calls that reaches no layer) is "other".
numpy is a layer by rule 1 (what the stack spends in numpy is worth knowing as such); the JSON and
the table also split it by the layer that called it (rule 2 applied with numpy left out of the
registry), so the range filter's numpy work can be added to it by the reader.

**Compiled or not.** cProfile sees Python functions only: in a process that runs the hot modules
compiled (mypyc, :mod:`protocol.compiled`), the plant, the firmware, the bus and the controller
would all be invisible, their time (and PyBullet's) booked to the nearest caller still in Python.
So :func:`write_profile`, asked in such a process, profiles in a child process that runs them as
pure Python (``ELEGANT_STEPPING_PURE_PYTHON=1``: the same trials, every layer visible) and reads
its files back: the profile is always of the pure-Python stack (``profile.json``: ``"python":
"pure"``). Compiling shrinks the Python layers, not PyBullet's or numpy's; read the shares so.

Caveats: cProfile's clock is the wall clock (``time.perf_counter``), and it adds a fixed cost to
every Python call, so the run takes two to three times as long as without it and the layers of
many small Python calls (the bus, the codec, the controller, the firmware simulation) take shares
from compiled code: ``stepSimulation`` measured about 7% here against the 16% a sampling profiler
(py-spy) gave the same stack (issue 17). The process CPU time of the profiled run is recorded
beside the total. Compare shares between two profiles made the same way, not with a sampling
profiler's or seconds with an unprofiled run. Rule 1 goes by file: the frame class's own
``__deepcopy__`` (protocol/) counts as the codec although only python-can's copy of each frame
calls it. The profile does not change what the run does (it only observes), so its trials are the
ones ``learn`` would give.

Files written into the folder: ``profile.json`` (stamped ``format: "bench-profile"``, version
:data:`PROFILE_VERSION`: the layers with seconds and share, the total, trials, seed, the top
:data:`TOP_N` functions by self time), ``profile.txt`` (the same as a table) and
``profile.pstats`` (the raw profile, for ``python -m pstats`` or snakeviz).

A new layer is one line in :data:`LAYERS`.
"""

from __future__ import annotations

import cProfile
import json
import logging
import os
import pstats
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

log = logging.getLogger(__name__)

PROFILE_KIND = "bench-profile"
PROFILE_VERSION = 1  # raise it when a reader of the old profile.json could misread the new
TOP_N = 30
OTHER = "other"
FILES = ("profile.json", "profile.txt", "profile.pstats")


@dataclass(frozen=True)
class Layer:
    """One layer of the stack in the profile's table.

    Attributes:
        key: the layer's key in ``profile.json``.
        label: the layer as the table names it.
        prefixes: qualified names (``module`` or ``module.function``) whose functions belong to it;
            a prefix matches itself and every dotted name below it.
    """

    key: str
    label: str
    prefixes: tuple[str, ...]


LAYERS: tuple[Layer, ...] = (
    Layer("bus", "python-can's bus", ("can",)),
    Layer("local_bus", "the lockstep's in-process bus (hil.lockstep.localbus)", ("hil.lockstep.localbus",)),
    Layer("step_simulation", "PyBullet stepSimulation", ("pybullet.stepSimulation",)),
    Layer("pybullet_calls", "other PyBullet calls (joint states, contacts, rays)", ("pybullet", "pybullet_utils")),
    Layer("range_filter", "range filter (filterpy + controller.stepping.range_filter)",
          ("filterpy", "controller.stepping.range_filter")),
    Layer("controller", "controller tick (controller/)", ("controller",)),
    Layer("protocol", "frame encode/decode (protocol/)", ("protocol",)),
    Layer("firmware_sim", "firmware simulation (firmware_sim/)", ("firmware_sim",)),
    Layer("hil", "ground truth and experiment (hil/)", ("hil",)),
    Layer("numpy", "numpy", ("numpy",)),
)
"""The layers, first match wins (a more specific prefix before its parent's layer)."""

LABELS: dict[str, str] = {**{layer.key: layer.label for layer in LAYERS}, OTHER: "other"}

Func = tuple[str, int, str]  # pstats' key: (file, line, function name); file "~" for a builtin
Classify = Callable[[Func], "str | None"]


def _matches(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def layer_of_name(qualified: str, layers: tuple[Layer, ...] = LAYERS) -> str | None:
    """The key of the first layer a qualified name (``module.function``) belongs to, else None."""
    for layer in layers:
        if any(_matches(qualified, p) for p in layer.prefixes):
            return layer.key
    return None


_BUILTIN = re.compile(r"<built-in method ([\w.]+)>")
_METHOD = re.compile(r"<method '(\w+)' of '([\w.]+)' objects>")


class Names:
    """The qualified name (``module.function``) of a profiled function, or None where it cannot be
    told (code compiled from a string, a builtin of an unnamed type)."""

    def __init__(self) -> None:
        self._modules: dict[str, str] = {}
        for name, module in list(sys.modules.items()):
            f = getattr(module, "__file__", None)
            if isinstance(f, str):
                self._modules.setdefault(os.path.realpath(f), name)
        self._roots = sorted({os.path.realpath(p) for p in sys.path if p and os.path.isdir(p)}, key=len, reverse=True)
        self._cache: dict[str, str | None] = {}

    def module_of_file(self, filename: str) -> str | None:
        if filename in self._cache:
            return self._cache[filename]
        found: str | None = None
        if not filename.startswith("<"):
            real = os.path.realpath(filename)
            found = self._modules.get(real)
            if found is None:  # a file not imported as a module of its own: name it by its place on sys.path
                for root in self._roots:
                    if real.startswith(root + os.sep):
                        rel = os.path.splitext(os.path.relpath(real, root))[0].split(os.sep)
                        found = ".".join(rel[:-1] if rel[-1] == "__init__" else rel)
                        break
        self._cache[filename] = found
        return found

    def __call__(self, func: Func) -> str | None:
        filename, _, name = func
        if filename == "~":
            m = _BUILTIN.fullmatch(name)
            if m:
                return m.group(1)
            m = _METHOD.fullmatch(name)
            if m:
                owner = m.group(2) if "." in m.group(2) else f"builtins.{m.group(2)}"  # dict, list, str: builtins
                return f"{owner}.{m.group(1)}"
            return None
        module = self.module_of_file(filename)
        return None if module is None else f"{module}.{name}"


def _stdlib(qualified: str | None) -> bool:
    """Whether a function passes its time to its callers (rule 2): the standard library's, or unknown."""
    if qualified is None:
        return True
    top = qualified.split(".", 1)[0]
    return top in sys.stdlib_module_names or top in ("builtins", "")


def classifier(names: Callable[[Func], str | None], layers: tuple[Layer, ...] = LAYERS) -> Classify:
    """A function's layer key (rule 1), :data:`OTHER` (rule 3), or None where its time goes to its
    callers (rule 2)."""

    def classify(func: Func) -> str | None:
        q = names(func)
        key = None if q is None else layer_of_name(q, layers)
        if key is not None:
            return key
        return None if _stdlib(q) else OTHER

    return classify


Stats = Mapping[Func, tuple[int, int, float, float, Mapping[Func, tuple[int, int, float, float]]]]


class Attribution:
    """Rule 2: the layers a function's self time goes to, from the call graph of ``stats``."""

    def __init__(self, stats: Stats, classify: Classify) -> None:
        self.stats = stats
        self.classify = classify
        self._owner: dict[Func, dict[str, float] | None] = {}
        self._cuts = 0  # cycles cut so far (a result computed across a cut is not kept)

    def owner(self, func: Func, _open: set[Func] | None = None) -> dict[str, float] | None:
        """The layers ``func``'s time belongs to, as fractions summing to 1; None where its callers
        lead only back into a cycle (the caller then leaves that edge out)."""
        key = self.classify(func)
        if key is not None:
            return {key: 1.0}
        if func in self._owner:
            return self._owner[func]
        _open = set() if _open is None else _open
        if func in _open:
            self._cuts += 1
            return None
        _open.add(func)
        cuts0 = self._cuts
        callers = self.stats[func][4] if func in self.stats else {}
        owners = [(edge, self.owner(caller, _open)) for caller, edge in callers.items()]
        owners = [(edge, o) for edge, o in owners if o is not None]
        _open.discard(func)
        result: dict[str, float] | None
        if not callers:
            result = {OTHER: 1.0}  # a root of the standard library: rule 3
        elif not owners:
            result = None  # every caller leads back into the cycle
        else:
            by_time = sum(edge[3] for edge, _ in owners) > 0  # weights: cumulative time, else calls
            weights = [(edge[3] if by_time else float(edge[1]), o) for edge, o in owners]
            total = sum(w for w, _ in weights) or 1.0
            result = {}
            for w, o in weights:
                for k, f in o.items():
                    result[k] = result.get(k, 0.0) + w / total * f
        if self._cuts == cuts0:  # a result that left out no open caller is the same from anywhere: keep it
            self._owner[func] = result
        return result

    def self_time(self, func: Func) -> dict[str, float]:
        """``func``'s self time [s] by layer: its own layer's, or split over its callers' edges."""
        tt, callers = self.stats[func][2], self.stats[func][4]
        key = self.classify(func)
        if key is not None:
            return {key: tt}
        out: dict[str, float] = {}
        edges = [(c, e[2]) for c, e in callers.items() if e[2] > 0]
        given = 0.0
        for caller, edge_tt in edges:
            o = self.owner(caller) or {OTHER: 1.0}
            for k, f in o.items():
                out[k] = out.get(k, 0.0) + edge_tt * f
            given += edge_tt
        rest = tt - given  # no caller recorded (a root) or rounding: other
        if rest > 0:
            out[OTHER] = out.get(OTHER, 0.0) + rest
        if given > tt > 0:  # edges summing past the total (cProfile rounding): scale back to the total
            out = {k: v * tt / given for k, v in out.items()}
        return out


def attribute(stats: Stats, classify: Classify, only: Callable[[Func], bool] | None = None) -> dict[str, float]:
    """Seconds of self time per layer key over every function (or those ``only`` accepts)."""
    a = Attribution(stats, classify)
    out: dict[str, float] = {}
    for func in stats:
        if only is not None and not only(func):
            continue
        for k, s in a.self_time(func).items():
            out[k] = out.get(k, 0.0) + s
    return out


def _where(func: Func, names: Names) -> str:
    filename, line, name = func
    if filename == "~":
        return name
    q = names(func)
    return f"{q}:{line}" if q else f"{filename}:{line}({name})"


def summarize(stats: Stats, names: Names | None = None, top_n: int = TOP_N) -> dict[str, Any]:
    """The layers (seconds, share; every layer of :data:`LAYERS`, then other), the total, numpy
    split by calling layer, and the ``top_n`` functions by self time."""
    names = Names() if names is None else names
    classify = classifier(names)
    by_layer = attribute(stats, classify)
    total = sum(by_layer.values())
    layers = {}
    for key in [layer.key for layer in LAYERS] + [OTHER]:
        s = by_layer.get(key, 0.0)
        layers[key] = {"label": LABELS[key], "seconds": s, "share": s / total if total > 0 else 0.0}
    def through_numpy(func: Func) -> str | None:  # numpy passes its time on to its callers, as rule 2
        key = classify(func)
        return None if key == "numpy" else key

    numpy_by_caller = {k: s for k, s in attribute(stats, through_numpy, only=lambda f: classify(f) == "numpy").items()
                       if s > 0.0}
    a = Attribution(stats, classify)
    top = sorted(stats, key=lambda f: stats[f][2], reverse=True)[:top_n]
    return {
        "total_s": total,
        "layers": layers,
        "numpy_by_caller_s": dict(sorted(numpy_by_caller.items(), key=lambda kv: -kv[1])),
        "top_functions": [
            {"function": _where(f, names), "calls": stats[f][1], "self_s": stats[f][2], "cumulative_s": stats[f][3],
             "layers_s": a.self_time(f)}
            for f in top
        ],
    }


def profile_learning(trials: int, seed: int) -> tuple[cProfile.Profile, dict[str, Any]]:
    """A learning run of ``trials`` trials with ``seed``, bring-up included, under cProfile; the
    profiler and what the run was (simulated, wall and CPU seconds, successes)."""
    from hil.experiments.learn import LearnConfig, LearningRun  # imported before the profiler starts

    run = None
    profiler = cProfile.Profile()
    wall0, cpu0 = time.perf_counter(), time.process_time()
    try:
        profiler.enable()
        run = LearningRun(LearnConfig(trials=trials, seed=seed))
        done = run.run()
        profiler.disable()
        sim_s = run.ls.t_s
    finally:
        profiler.disable()
        if run is not None:
            run.close()
    return profiler, {"trials": trials, "seed": seed, "sim_s": sim_s, "wall_s": time.perf_counter() - wall0,
                      "cpu_s": time.process_time() - cpu0, "successes": sum(bool(t["success"]) for t in done)}


def table(result: Mapping[str, Any]) -> str:
    """``profile.json``'s content as the human-readable table of ``profile.txt``."""
    lines = [f"elegant-stepping bench --profile: learning run, {result['trials']} trial(s), seed {result['seed']}, "
             f"bring-up included, under cProfile, hot modules as pure Python",
             f"simulated {result['sim_s']:.2f} s; profiled run {result['wall_s']:.2f} s wall, "
             f"{result['cpu_s']:.2f} s CPU; self time attributed {result['total_s']:.3f} s",
             "",
             f"{'layer':<62}{'seconds':>9}{'share':>8}"]
    for layer in result["layers"].values():
        lines.append(f"{layer['label']:<62}{layer['seconds']:>9.3f}{layer['share']:>8.1%}")
    lines.append(f"{'total':<62}{result['total_s']:>9.3f}{1.0 if result['total_s'] > 0 else 0.0:>8.1%}")
    if result["numpy_by_caller_s"]:
        lines += ["", "numpy, by the layer that called it:"]
        for key, s in result["numpy_by_caller_s"].items():
            if s >= 0.0005:  # what would print as 0.000 is left out of the table (not of the JSON)
                lines.append(f"  {LABELS.get(key, key):<60}{s:>9.3f}")
    lines += ["", f"top {len(result['top_functions'])} functions by self time (seconds, calls, layer):"]
    for f in result["top_functions"]:
        owners = ", ".join(f"{k}" if len(f["layers_s"]) == 1 else f"{k} {v / f['self_s']:.0%}"
                           for k, v in sorted(f["layers_s"].items(), key=lambda kv: -kv[1]) if f["self_s"] > 0)
        lines.append(f"  {f['self_s']:>8.3f} {f['calls']:>9}  {f['function']}  [{owners}]")
    return "\n".join(lines) + "\n"


def write_profile(out_dir: str | os.PathLike, trials: int = 3, seed: int = 0) -> dict[str, Any]:
    """Profile a learning run (:func:`profile_learning`) and write :data:`FILES` into ``out_dir``
    (made if missing); return what ``profile.json`` holds. In a process running hot modules
    compiled, the run is profiled in a pure-Python child process (the module's docstring)."""
    from controller.atomic import write_json_atomic, write_text_atomic
    from controller.errors import stamp
    from protocol.compiled import PURE_PYTHON_ENV, compiled_modules

    out = Path(out_dir)
    if compiled_modules():
        return _write_profile_pure(out, trials, seed, PURE_PYTHON_ENV)
    profiler, run = profile_learning(trials, seed)
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    result = {**stamp(PROFILE_KIND, PROFILE_VERSION), "profiler": "cProfile (perf_counter clock)", "python": "pure",
              **run, **summarize(stats)}
    out.mkdir(parents=True, exist_ok=True)
    profiler.dump_stats(str(out / "profile.pstats"))
    write_json_atomic(out / "profile.json", result)
    write_text_atomic(out / "profile.txt", table(result))
    log.info("wrote %s", ", ".join(str(out / f) for f in FILES))
    return result


def _write_profile_pure(out: Path, trials: int, seed: int, pure_env: str) -> dict[str, Any]:
    """:func:`write_profile` in a child process running every hot module as pure Python (this
    module run as a script); its ``profile.json``, read back. The child's failure is this one's."""
    env = {**os.environ, pure_env: "1"}
    cmd = [sys.executable, "-m", __name__, str(out), str(trials), str(seed)]
    done = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        tail = done.stderr.strip().splitlines()[-1:] or ["no message"]
        raise RuntimeError(f"the pure-Python profile run failed (exit {done.returncode}): {tail[0]}")
    return json.loads((out / "profile.json").read_text())


if __name__ == "__main__":  # the child process of _write_profile_pure: OUT_DIR TRIALS SEED
    write_profile(sys.argv[1], trials=int(sys.argv[2]), seed=int(sys.argv[3]))

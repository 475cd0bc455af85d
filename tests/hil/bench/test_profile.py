"""``bench --profile DIR`` (hil.bench.profile): a learning run's self time per layer of the stack.

One real 1-trial profile is made (module fixture) and checked for its files and structure, never
for its seconds; the attribution rules are checked on call graphs built by hand; the command line
refuses a DIR it could not write before anything runs."""

from __future__ import annotations

import json
import math
import pstats

import pytest

from controller.errors import check_stamp
from hil.bench import profile as prof
from hil.cli import main

MUST_HAVE_TIME = ("step_simulation", "controller", "firmware_sim", "bus", "local_bus")

@pytest.fixture(scope="module")
def made(tmp_path_factory):
    out = tmp_path_factory.mktemp("profile") / "deep" / "dir"  # made by the profile, parents too
    result = prof.write_profile(out, trials=1, seed=0)
    return out, result


def test_a_one_trial_profile_writes_the_three_files(made):
    out, result = made
    assert sorted(p.name for p in out.iterdir()) == sorted(prof.FILES)
    data = json.loads((out / "profile.json").read_text())
    assert check_stamp(data, prof.PROFILE_KIND, [prof.PROFILE_VERSION], "profile.json") == prof.PROFILE_VERSION
    assert list(data)[:3] == ["format", "format_version", "project_version"]
    assert (data["trials"], data["seed"]) == (1, 0) and data["sim_s"] > 0
    assert data == json.loads(json.dumps(result))
    raw = pstats.Stats(str(out / "profile.pstats")).stats  # type: ignore[attr-defined]
    assert any(name == "<built-in method pybullet.stepSimulation>" for _, _, name in raw)
    assert data["python"] == "pure"  # a compiled process profiles in a pure-Python child: cProfile sees every layer
    assert any(file.endswith("firmware_sim/plant.py") for file, _, _ in raw)
    text = (out / "profile.txt").read_text()
    for layer in data["layers"].values():
        assert layer["label"] in text
    assert "top 30 functions by self time" in text


def test_the_shares_sum_to_one_and_every_layer_is_listed(made):
    _, result = made
    layers = result["layers"]
    assert list(layers) == [layer.key for layer in prof.LAYERS] + [prof.OTHER]
    assert math.isclose(sum(v["share"] for v in layers.values()), 1.0, rel_tol=1e-9)
    assert math.isclose(sum(v["seconds"] for v in layers.values()), result["total_s"], rel_tol=1e-9)
    assert all(v["seconds"] >= 0.0 for v in layers.values())


@pytest.mark.parametrize("key", MUST_HAVE_TIME)
def test_the_layers_of_the_hot_path_have_time(made, key):
    assert made[1]["layers"][key]["seconds"] > 0.0


def test_the_top_functions_are_thirty_in_order_with_their_layers(made):
    top = made[1]["top_functions"]
    assert len(top) == prof.TOP_N
    self_s = [f["self_s"] for f in top]
    assert self_s == sorted(self_s, reverse=True)
    for f in top:  # each function's self time is handed out whole, to layers of the registry or other
        assert set(f["layers_s"]) <= {layer.key for layer in prof.LAYERS} | {prof.OTHER}
        assert math.isclose(sum(f["layers_s"].values()), f["self_s"], rel_tol=1e-9, abs_tol=1e-12)
    step = next(f for f in top if f["function"] == "<built-in method pybullet.stepSimulation>")
    assert list(step["layers_s"]) == ["step_simulation"]


# ---- the rules, on call graphs built by hand -------------------------------------------------------------------

def _names(table: dict[str, str]):
    """A stand-in for :class:`hil.bench.profile.Names`: the qualified name by function name."""
    return lambda func: table.get(func[2])


def _f(name: str) -> prof.Func:
    return ("x.py", 1, name)


def _stats(edges: dict[str, dict[str, tuple[float, float]]], self_s: dict[str, float]):
    """pstats' mapping from ``edges[callee][caller] = (edge self s, edge cumulative s)``."""
    out = {}
    for name, tt in self_s.items():
        callers = {_f(c): (1, 1, e_tt, e_ct) for c, (e_tt, e_ct) in edges.get(name, {}).items()}
        out[_f(name)] = (1, 1, tt, sum(e[3] for e in callers.values()) or tt, callers)
    return out


def test_rule_1_the_first_matching_layer_wins():
    assert prof.layer_of_name("pybullet.stepSimulation") == "step_simulation"
    assert prof.layer_of_name("pybullet.getJointStates") == "pybullet_calls"
    assert prof.layer_of_name("controller.stepping.range_filter.predict") == "range_filter"
    assert prof.layer_of_name("filterpy.kalman.kalman_filter.predict") == "range_filter"
    assert prof.layer_of_name("controller.loop.tick") == "controller"
    assert prof.layer_of_name("can.interfaces.virtual.send") == "bus"
    assert prof.layer_of_name("candy.send") is None  # a prefix matches whole dotted names only
    assert prof.layer_of_name("numpy.ndarray.copy") == "numpy"


def test_builtins_are_named_by_the_module_in_their_label():
    names = prof.Names()
    assert names(("~", 0, "<built-in method pybullet.stepSimulation>")) == "pybullet.stepSimulation"
    assert names(("~", 0, "<method 'copy' of 'numpy.ndarray' objects>")) == "numpy.ndarray.copy"
    assert names(("~", 0, "<method 'get' of 'dict' objects>")) == "builtins.dict.get"
    assert names(("~", 0, "<built-in method __new__ of type object at 0x7f>")) is None
    assert names((prof.__file__, 1, "table")) == "hil.bench.profile.table"


def test_rule_2_the_standard_library_s_time_goes_to_its_callers_edge_by_edge():
    names = _names({"send": "can.interfaces.virtual.send", "tick": "controller.loop.tick",
                    "deepcopy": "copy.deepcopy", "put": "queue.Queue.put", "len": "builtins.len",
                    "scipy": "scipy.linalg.inv"})
    stats = _stats(
        {"deepcopy": {"send": (0.3, 0.5), "deepcopy": (0.1, 0.2)},  # recursive: the cycle is cut where it closes
         "put": {"send": (0.2, 0.2)},
         "len": {"tick": (0.1, 0.1), "deepcopy": (0.2, 0.2)},  # deepcopy's share goes on up to send
         "send": {}, "tick": {}, "scipy": {"tick": (0.5, 0.5)}},
        {"send": 1.0, "tick": 2.0, "deepcopy": 0.4, "put": 0.2, "len": 0.3, "scipy": 0.5})
    by_layer = prof.attribute(stats, prof.classifier(names))
    assert by_layer == pytest.approx({"bus": 1.0 + 0.4 + 0.2 + 0.2, "controller": 2.0 + 0.1, "other": 0.5})
    assert sum(by_layer.values()) == pytest.approx(sum(s[2] for s in stats.values()))


def test_rule_2_splits_by_the_callers_own_callers_when_they_are_standard_library_too():
    names = _names({"send": "can.bus.send", "tick": "controller.loop.tick", "helper": "copy.helper",
                    "len": "builtins.len"})
    stats = _stats({"helper": {"send": (0.1, 0.3), "tick": (0.1, 0.1)},  # cumulative 3:1
                    "len": {"helper": (0.4, 0.4)}, "send": {}, "tick": {}},
                   {"send": 0.0, "tick": 0.0, "helper": 0.2, "len": 0.4})
    by_layer = prof.attribute(stats, prof.classifier(names))
    assert by_layer == pytest.approx({"bus": 0.1 + 0.3, "controller": 0.1 + 0.1})


def test_a_standard_library_root_is_other():
    names = _names({"main": "runpy.main"})
    stats = _stats({"main": {}}, {"main": 0.7})
    assert prof.attribute(stats, prof.classifier(names)) == pytest.approx({"other": 0.7})


def test_the_table_lists_every_layer_and_the_total(made):
    text = prof.table(made[1])
    for key in [layer.key for layer in prof.LAYERS] + [prof.OTHER]:
        assert prof.LABELS[key] in text
    assert "total" in text and "100.0%" in text


# ---- the command line ----------------------------------------------------------------------------------------

@pytest.fixture
def no_run(monkeypatch):
    """Fail the test if anything is profiled or measured (the refusal must come first)."""

    def started(*args, **kwargs):
        raise AssertionError("a profile or a figure was started")

    monkeypatch.setattr(prof, "profile_learning", started)
    import hil.bench.run

    monkeypatch.setattr(hil.bench.run, "run_bench", started)


def test_the_cli_refuses_a_dir_under_a_file_before_anything_runs(tmp_path, capsys, no_run):
    (tmp_path / "a_file").write_text("mine")
    assert main(["bench", "--profile", str(tmp_path / "a_file" / "prof")]) == 3
    err = capsys.readouterr().err
    assert f"--profile {tmp_path}/a_file/prof: {tmp_path}/a_file is a file" in err, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert (tmp_path / "a_file").read_text() == "mine"


@pytest.mark.parametrize("extra", [["--json", "x.json"], ["--hil"]])
def test_the_cli_refuses_the_figures_options_beside_profile(tmp_path, capsys, no_run, extra):
    assert main(["bench", "--profile", str(tmp_path / "p"), *extra]) == 2
    err = capsys.readouterr().err
    assert "--profile writes only the profile" in err and extra[0] in err
    assert not (tmp_path / "p").exists()


def test_the_cli_writes_the_profile_and_prints_its_table(tmp_path, capsys, monkeypatch):
    calls = []

    def fake(out_dir, trials, seed):
        calls.append((str(out_dir), trials, seed))
        return {"trials": trials, "seed": seed, "sim_s": 1.0, "wall_s": 1.0, "cpu_s": 1.0, "total_s": 1.0,
                "layers": {"bus": {"label": "python-can's bus", "seconds": 1.0, "share": 1.0}},
                "numpy_by_caller_s": {}, "top_functions": []}

    monkeypatch.setattr(prof, "write_profile", fake)
    assert main(["bench", "--profile", str(tmp_path / "p"), "--profile-trials", "2", "--seed", "4"]) == 0
    assert calls == [(str(tmp_path / "p"), 2, 4)]
    assert "python-can's bus" in capsys.readouterr().out


def test_profile_trials_must_be_positive(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--profile", str(tmp_path / "p"), "--profile-trials", "0"])
    assert exc.value.code == 2 and "argument --profile-trials:" in capsys.readouterr().err


def test_a_failed_pure_python_child_is_one_line_naming_it(tmp_path):
    (tmp_path / "a_file").write_text("mine")
    with pytest.raises(RuntimeError) as exc:
        prof._write_profile_pure(tmp_path / "a_file" / "p", 1, 0, "ELEGANT_STEPPING_PURE_PYTHON")
    message = str(exc.value)
    assert message.startswith("the pure-Python profile run failed (exit 1): ") and "\n" not in message
    assert (tmp_path / "a_file").read_text() == "mine"

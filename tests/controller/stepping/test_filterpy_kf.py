"""filterpy's KalmanFilter loaded without the rest of filterpy (controller.stepping.filterpy_kf):
the same numbers as filterpy's class, no scipy at import, and the whole package (with a warning)
when the installed filterpy is not shaped as expected."""

from __future__ import annotations

import importlib.util
import json
import logging
import pickle
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from controller.stepping import filterpy_kf
from controller.stepping.filterpy_kf import KalmanFilter


def _filterpy_file(*parts: str) -> str:
    spec = importlib.util.find_spec("filterpy")
    return str(Path(next(iter(spec.submodule_search_locations)), *parts))


def test_the_installed_filterpy_takes_the_light_load():
    # constraints.txt pins the filterpy CI installs: a release that breaks the light load fails here
    assert filterpy_kf.LIGHT is True
    assert KalmanFilter.__module__ == "controller.stepping.filterpy_kf"
    assert KalmanFilter.predict.__code__.co_filename == _filterpy_file("kalman", "kalman_filter.py")
    assert KalmanFilter.update.__globals__["reshape_z"].__code__.co_filename == _filterpy_file("common", "helpers.py")


def _run(cls, steps: int = 200) -> list[tuple[np.ndarray, ...]]:
    """A constant-velocity filter as the range filter runs it: predicts with two dts, an update
    every tenth, a likelihood read after each update (the lazily imported logpdf)."""
    rng = np.random.default_rng(4)
    kf = cls(dim_x=2, dim_z=1)
    kf.H = np.array([[1.0, 0.0]])
    kf.R = np.array([[0.02**2]])
    kf.x = np.array([[2.5], [0.0]])
    kf.P = np.diag([0.02**2, 1.0])
    out = []
    for i in range(steps):
        dt = 0.002 if i % 3 else 0.0020000000000000018
        kf.F = np.array([[1.0, dt], [0.0, 1.0]])
        kf.Q = 0.09 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
        kf.predict()
        if i % 10 == 9:
            kf.update(np.array([[2.5 - 0.5 * i * 0.002 + rng.normal(0.0, 0.02)]]))
            out.append((kf.x.copy(), kf.P.copy(), kf.K.copy(), kf.y.copy(), kf.S.copy(),
                        np.array(kf.log_likelihood), np.array(kf.mahalanobis)))
        out.append((kf.x.copy(), kf.P.copy()))
    return out


def test_its_numbers_are_filterpys_bit_for_bit():
    from filterpy.kalman import KalmanFilter as Full  # the whole package, as before

    assert KalmanFilter is not Full
    light, full = _run(KalmanFilter), _run(Full)
    assert len(light) == len(full) == 220
    for a, b in zip(light, full):
        assert len(a) == len(b)
        for u, v in zip(a, b):
            assert u.shape == v.shape and u.tobytes() == v.tobytes()


def test_a_filter_pickles_and_prints_as_filterpys():
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.x = np.array([[1.5], [-0.5]])
    copy = pickle.loads(pickle.dumps(kf))
    assert type(copy) is KalmanFilter
    assert copy.x.tobytes() == kf.x.tobytes()
    assert "dim_x = 2" in repr(kf)  # filterpy's pretty_str, from its helpers


def _modules_after(code: str) -> dict:
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_range_filter_imports_neither_scipy_nor_filterpys_package_until_a_likelihood_is_asked():
    seen = _modules_after("""
        import json, sys
        import numpy as np
        def loaded():
            return sorted(m for m in sys.modules if m.partition(".")[0] in ("scipy", "filterpy"))
        from controller.stepping.range_filter import RangeFilter
        f = RangeFilter()
        for i in range(60):
            f.predict(i * 0.002)
            if i % 10 == 9:
                f.reading(2.0 - i * 0.001, True, i * 0.002)
        before = loaded()
        ll = float(f.kf.log_likelihood)
        print(json.dumps({"before": before, "after": loaded(), "ll": ll}))
    """)
    assert seen["before"] == []
    assert "scipy.stats" in seen["after"] and "filterpy.stats" in seen["after"]
    assert np.isfinite(seen["ll"])


# -- a filterpy not shaped as expected: the whole package, and a warning ---------------------------

HELPERS = """
import copy
import numpy as np

def pretty_str(label, arr):
    return f"{label} = {arr}"

def reshape_z(z, dim_z, ndim):
    return np.atleast_2d(z)
"""

KALMAN = """
from __future__ import absolute_import, division
import numpy as np
from filterpy.stats import logpdf
from filterpy.common import pretty_str, reshape_z

class KalmanFilter(object):
    def __init__(self, dim_x, dim_z):
        self.x = np.zeros((dim_x, 1))

    def likelihood(self):
        return logpdf(0.0, 1.0)
"""


def _fake_filterpy(root: Path, monkeypatch, kalman: str = KALMAN, helpers: str = HELPERS) -> None:
    for sub, text in (("kalman/kalman_filter.py", kalman), ("common/helpers.py", helpers)):
        if text is not None:
            (root / "filterpy" / sub).parent.mkdir(parents=True, exist_ok=True)
            (root / "filterpy" / sub).write_text(textwrap.dedent(text))
    monkeypatch.setattr(filterpy_kf, "_package_dir", lambda: root / "filterpy")


def test_a_filterpy_shaped_as_expected_loads_light(tmp_path, monkeypatch):
    _fake_filterpy(tmp_path, monkeypatch)
    cls = filterpy_kf._load_light()
    assert cls.__init__.__code__.co_filename == str(tmp_path / "filterpy" / "kalman" / "kalman_filter.py")
    assert cls(3, 1).x.shape == (3, 1)
    assert cls.likelihood.__globals__["logpdf"] is filterpy_kf._logpdf
    assert cls.likelihood.__globals__["reshape_z"].__code__.co_filename.endswith("helpers.py")


@pytest.mark.parametrize("kalman,helpers,reason", [
    (KALMAN.replace("import numpy as np", "import numpy as np\nimport scipy.linalg"), HELPERS, "imports scipy.linalg"),
    (KALMAN.replace("pretty_str, reshape_z", "pretty_str, reshape_z, Saver"), HELPERS, "imports filterpy.common"),
    (KALMAN.replace("from filterpy.stats import logpdf\n", "")
     + "\ndef later():\n    from filterpy.stats import logpdf\n", HELPERS, "imports filterpy.stats"),
    (KALMAN.replace("from filterpy.stats import logpdf", "from ..stats import logpdf"), HELPERS, "relative import"),
    (KALMAN.replace("class KalmanFilter", "class KalmanFilter2"), HELPERS, "defines no class KalmanFilter"),
    (KALMAN, HELPERS.replace("import copy", "import scipy"), "imports scipy"),
    (KALMAN, HELPERS.replace("def reshape_z", "def reshape"), "defines no reshape_z"),
    (KALMAN, None, "cannot read"),
    (KALMAN + "\ndef (:\n", HELPERS, "cannot read"),
    (KALMAN + "\nundefined_name\n", HELPERS, "running .* failed: NameError"),
], ids=["third-party", "another-filterpy-name", "filterpy-in-a-function", "relative", "no-class",
        "helpers-third-party", "helpers-without-reshape_z", "no-helpers", "syntax", "fails-to-run"])
def test_a_filterpy_shaped_otherwise_is_refused(tmp_path, monkeypatch, kalman, helpers, reason):
    _fake_filterpy(tmp_path, monkeypatch, kalman, helpers)
    with pytest.raises(filterpy_kf._Unexpected, match=reason):
        filterpy_kf._load_light()


def test_when_refused_the_whole_filterpy_is_used_with_a_warning(tmp_path, monkeypatch, caplog):
    from filterpy.kalman import KalmanFilter as Full

    _fake_filterpy(tmp_path, monkeypatch, KALMAN.replace("import numpy as np", "import numpy as np\nimport scipy"))
    with caplog.at_level(logging.WARNING, logger="controller.stepping.filterpy_kf"):
        cls, light = filterpy_kf._load()
    assert cls is Full and light is False
    assert any(r.levelno == logging.WARNING and "imports scipy" in r.getMessage() for r in caplog.records)

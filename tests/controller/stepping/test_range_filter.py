"""The Kalman range filter and the range encoder."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.stepping.encoder import RangeEncoder, RangeEncoderConfig
from controller.stepping.range_filter import RangeFilter, RangeFilterConfig, inverse_1x1


def approach(f: RangeFilter, rng, d0=2.5, v=-0.5, seconds=2.0, noise=0.02, dropout=0.0, tick=0.002):
    """Feed an approaching target; readings at 50 Hz, predictions every tick. Returns true d."""
    t, d = 0.0, d0
    for i in range(int(seconds / tick)):
        t = (i + 1) * tick
        d = d0 + v * t
        f.predict(t)
        if i % 10 == 9:
            valid = rng.random() >= dropout
            f.reading(d + rng.normal(0.0, noise), valid, t)
    return d


def test_filter_beats_the_raw_noise_and_tracks_the_closing_speed():
    rng = np.random.default_rng(0)
    errors = []
    for seed in range(20):
        f = RangeFilter()
        d = approach(f, np.random.default_rng(seed))
        errors.append(f.estimate_m - d)
        assert f.rate_m_s == pytest.approx(-0.5, abs=0.08)
        assert 0.0 < f.rate_var_m2_s2 < 0.03 ** 2  # from 1 at acquisition: the rate is known
    rms = math.sqrt(sum(e * e for e in errors) / len(errors))
    assert rms < 0.02 / 2, f"filtered rms {rms:.4f} m is not better than half the raw 0.02 m"
    assert rng is not None


def test_the_1x1_inverse_is_numpys_bit_for_bit_and_so_is_the_filter():
    rng = np.random.default_rng(1)
    for v in rng.uniform(0.5, 1.0, 3000) * 10.0 ** rng.integers(-20, 20, 3000):
        s = np.array([[v]])
        assert inverse_1x1(s).tobytes() == np.linalg.inv(s).tobytes()
    ours, numpys = RangeFilter(), RangeFilter()
    numpys.kf.inv = np.linalg.inv  # filterpy's default
    assert ours.kf.inv is inverse_1x1
    for f in (ours, numpys):
        approach(f, np.random.default_rng(7), dropout=0.2)
    assert ours.kf.x.tobytes() == numpys.kf.x.tobytes() and ours.kf.P.tobytes() == numpys.kf.P.tobytes()
    assert ours.used == numpys.used > 50


@pytest.mark.parametrize("s", [np.eye(2) * 3.0, np.array([[0.0]]), np.array([[-2.0]]), np.array([[np.inf]])])
def test_anything_but_a_positive_finite_1x1_goes_to_numpy(s):
    """numpy's answer (or its LinAlgError for a singular matrix), never a reciprocal of its own."""
    try:
        want = np.linalg.inv(s)
    except np.linalg.LinAlgError:
        with pytest.raises(np.linalg.LinAlgError):
            inverse_1x1(s)
    else:
        assert inverse_1x1(s).tobytes() == want.tobytes()


def test_dropouts_mean_predict_only_and_are_counted():
    f = RangeFilter()
    d = approach(f, np.random.default_rng(1), dropout=0.3)
    assert f.dropouts > 10
    assert f.estimate_m == pytest.approx(d, abs=0.02)


@pytest.mark.parametrize("value,counter", [(math.nan, "nan"), (-0.1, "out_of_range"), (3.5, "out_of_range")])
def test_bad_readings_are_rejected_and_counted(value, counter):
    f = RangeFilter()
    f.predict(0.0)
    f.reading(1.0, True, 0.0)
    f.predict(0.02)
    assert not f.reading(value, True, 0.02)
    assert f.rejected[counter] == 1
    assert f.estimate_m == pytest.approx(1.0)


def test_stale_readings_are_rejected():
    f = RangeFilter()
    f.predict(0.0)
    assert f.reading(1.0, True, 0.10)
    assert not f.reading(0.9, True, 0.10)
    assert not f.reading(0.9, True, 0.05)
    assert f.rejected["stale"] == 2


def test_an_outlier_is_dropped_but_a_run_of_them_is_a_new_target():
    f = RangeFilter(RangeFilterConfig(reacquire_after=3))
    rng = np.random.default_rng(2)
    approach(f, rng, d0=2.0, v=0.0, seconds=1.0)
    t = 1.0
    f.predict(t + 0.02)
    assert not f.reading(0.5, True, t + 0.02)  # a spurious short reading
    assert f.estimate_m == pytest.approx(2.0, abs=0.02)
    for k in range(2, 4):
        f.predict(t + 0.02 * k)
        f.reading(0.5, True, t + 0.02 * k)
    assert f.estimate_m == pytest.approx(0.5, abs=0.01)  # a new, nearer target came into view
    assert f.rejected["outlier"] == 3


def test_estimate_is_withdrawn_when_the_target_leaves_view():
    f = RangeFilter(RangeFilterConfig(stale_s=0.25))
    f.predict(0.0)
    f.reading(1.0, True, 0.0)
    f.predict(0.2)
    assert f.estimate_m is not None
    assert f.rate_var_m2_s2 is not None
    f.predict(0.3)
    assert f.estimate_m is None and f.rate_m_s is None and f.rate_var_m2_s2 is None


def test_encoder_cells_do_not_overlap_and_cover_the_range():
    enc = RangeEncoder(RangeEncoderConfig(cell_width_m=0.04, max_range_m=3.0))
    assert enc.n_cells == 75
    assert [enc.cell(d) for d in (0.0, 0.039, 0.04, 1.0, 2.999)] == [0, 0, 1, 25, 74]
    assert enc.cell(3.0) is None and enc.cell(-0.01) is None and enc.cell(None) is None and enc.cell(math.nan) is None
    with pytest.raises(ValueError):
        RangeEncoderConfig(cell_width_m=0.0)

"""Localisation pieces on synthetic residuals (civic/diagnose/locate.py)."""
from __future__ import annotations

import numpy as np
import pytest

from civic.diagnose.locate import ONSET_LR, change_interval, change_point, reading_step


def _windows(n, w=5.0):
    t0 = np.arange(n) * w
    return np.stack([t0, t0 + w], axis=1)


def test_change_point_dates_a_share_that_changes_and_brackets_an_idle_stretch():
    """r = 0.3 q from window 120 on (a line passing 30 % less): the split, the share and a bracket
    that spans the windows the line was shut (q = 0) before it; the same share throughout (a
    coefficient off) has no significant split."""
    rng = np.random.default_rng(3)
    n, sigma = 240, 0.05
    q = 0.5 + 0.3 * np.sin(np.arange(n) / 7.0) ** 2
    q[105:120] = 0.0                           # shut from 525 s to 600 s
    r = np.where(np.arange(n) >= 120, 0.3 * q, 0.0) + rng.normal(0.0, sigma, n)
    t, z, share, lo, hi = change_point(r, q, _windows(n), sigma)
    assert abs(share - 0.3) < 0.02 and z > 20
    assert lo <= 525.0 and hi >= 600.0 and hi - lo <= 100.0
    r_const = 0.3 * q + rng.normal(0.0, sigma, n)
    assert change_point(r_const, q, _windows(n), sigma)[1] ** 2 < 3 * ONSET_LR


def test_a_change_while_the_line_is_shut_is_dated_in_the_middle_of_that_stretch():
    """The line is shut from 525 to 600 s: a clog from 525 s and one from 600 s leave the same
    record, so they get the same date, the middle of the stretch (the best split alone said
    600 s, the stretch's end, for both: 75 s off for the first)."""
    n, sigma = 240, 0.05
    q = 0.5 + 0.3 * np.sin(np.arange(n) / 7.0) ** 2
    q[105:120] = 0.0
    dates = []
    for onset in (105, 120):
        rng = np.random.default_rng(3)
        r = np.where(np.arange(n) >= onset, 0.3 * q, 0.0) + rng.normal(0.0, sigma, n)
        t, z, share, lo, hi = change_point(r, q, _windows(n), sigma)
        assert lo <= onset * 5.0 <= hi
        dates.append(t)
    assert dates[0] == dates[1] and 555.0 <= dates[0] <= 570.0


def test_change_interval_dates_an_end_in_the_middle_of_a_shut_stretch():
    """A valve closed 300-700 s while its line is shut from 650 to 750 s: the end is dated in
    the middle of the shut stretch, the onset where the line passes flow."""
    rng = np.random.default_rng(7)
    n, sigma = 240, 0.05
    q = 0.5 + 0.3 * np.sin(np.arange(n) / 7.0) ** 2
    q[130:150] = 0.0
    k = np.arange(n)
    r = np.where((k >= 60) & (k < 140), 0.4 * q, 0.0) + rng.normal(0.0, sigma, n)
    sp = change_interval(r, q, _windows(n), sigma)
    assert sp.on == 300.0 and 690.0 <= sp.off <= 710.0
    assert sp.off_lo <= 650.0 and sp.off_hi >= 750.0


def test_change_interval_dates_both_ends_of_a_fault_that_ended():
    """r = 0.4 q from window 60 to window 140 only (a valve closed for 400 s, opened again): the
    interval, its share and a bracket round each end; the single change point cannot fit it. A
    fault that stays to the end (one change) or a share that never changes: no interval."""
    rng = np.random.default_rng(7)
    n, sigma = 240, 0.05
    q = 0.5 + 0.3 * np.sin(np.arange(n) / 7.0) ** 2
    k = np.arange(n)
    r = np.where((k >= 60) & (k < 140), 0.4 * q, 0.0) + rng.normal(0.0, sigma, n)
    sp = change_interval(r, q, _windows(n), sigma)
    assert (sp.on, sp.off) == (300.0, 700.0) and abs(sp.share - 0.4) < 0.02 and sp.z > 20
    assert sp.on_lo <= 300.0 <= sp.on_hi and sp.off_lo <= 700.0 <= sp.off_hi
    assert sp.on_hi - sp.on_lo <= 20.0 and sp.off_hi - sp.off_lo <= 20.0
    to_the_end = np.where(k >= 60, 0.4 * q, 0.0) + rng.normal(0.0, sigma, n)
    assert change_interval(to_the_end, q, _windows(n), sigma) is None
    assert change_interval(0.3 * q + rng.normal(0.0, sigma, n), q, _windows(n), sigma) is None


def test_change_point_weighs_windows_not_flow_near_the_ends():
    """A loop that drives a clogged pump four times harder after the onset: the flow's weight
    before it is small, the split is still found where it is (the edge counts windows)."""
    rng = np.random.default_rng(4)
    n, sigma = 360, 0.05
    q = np.where(np.arange(n) < 60, 0.37, 1.5)
    r = np.where(np.arange(n) >= 60, -0.4 * q, 0.0) + rng.normal(0.0, sigma, n)
    t, z, share, lo, hi = change_point(r, q, _windows(n), sigma)
    assert t == 300.0 and abs(share + 0.4) < 0.02
    assert lo <= 300.0 <= hi


def test_change_point_judges_an_early_step_against_the_spread_left_around_it():
    """A pump line clogged by 40 % from the first quarter of the record on: the residual's own
    robust spread (what the diagnosis weighs a balance by) is mostly the fault, yet the step
    stands out against the noise left around the two-share fit; the bracket stays as wide as
    that whole-residual spread makes it."""
    from civic.plant.noise import robust_sigma

    rng = np.random.default_rng(5)
    n, noise = 360, 0.02
    q = 0.4 + 0.6 * rng.uniform(size=n)
    r = np.where(np.arange(n) >= 90, -0.4 * q, 0.0) + rng.normal(0.0, noise, n)
    sigma = robust_sigma(r - np.median(r))              # inflated by the fault: ~7x the noise
    assert sigma > 5 * noise
    t, z, share, lo, hi = change_point(r, q, _windows(n), sigma)
    z_noise = change_point(r, q, _windows(n), noise)[1]      # judged against the true noise
    assert t == 450.0 and abs(share + 0.4) < 0.02
    assert z > 0.5 * z_noise and lo <= 450.0 <= hi


def test_reading_step_dates_a_step_to_the_sample_and_ignores_drift():
    """The unexplained volume of a tank whose reading steps by 0.1 at sample 3023 (noise 0.02, a
    slow drift of model error on top): dated to that sample, the step's size and sign; outside
    the searched span, or in noise alone, no step stands out."""
    rng = np.random.default_rng(8)
    n, dt = 6000, 0.1
    t = np.arange(n) * dt
    u = 0.002 * t + rng.normal(0.0, 0.02, n) + np.where(np.arange(n) >= 3023, -0.1, 0.0)
    when, z, step, lo, hi = reading_step(u, dt, 250.0, 350.0)
    assert when == pytest.approx(302.3) and lo <= 302.3 <= hi and hi - lo <= 1.0
    assert step == pytest.approx(-0.1, abs=0.03) and z > 5      # 1 s either side: se 0.009
    assert reading_step(u, dt, 320.0, 400.0)[1] < 5.0
    assert reading_step(rng.normal(0.0, 0.02, n), dt, 0.0, 600.0)[1] < 5.0
    # a step down and (sign +1) the sharpest step up: none out of the noise, until it steps back
    assert reading_step(u, dt, 0.0, 600.0, sign=1.0)[1] < 5.0
    back = u + np.where(np.arange(n) >= 4517, 0.1, 0.0)
    when, z, step, lo, hi = reading_step(back, dt, 0.0, 600.0, sign=1.0)
    assert when == pytest.approx(451.7) and step == pytest.approx(0.1, abs=0.03) and z > 5

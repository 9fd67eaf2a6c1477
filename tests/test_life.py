"""L10 rating life, docs/model.md §5 item 10: L10 = (C/F_m)³ · 10⁶ revolutions, F_m the cubic mean
load weighted by revolutions (vendor catalogues). Reference values are computed by hand below."""

import math

import numpy as np
import pytest

from prsm_sim.life import cubic_mean_load, l10_revolutions, life_from_samples

# Duty cycle worked by hand: 1000 revolutions at 2 kN, then 500 at 4 kN, C_a = 30 kN.
#   Σ F³ n = 2000³·1000 + 4000³·500 = 8e12 + 3.2e13 = 4e13 N³·rev,  Σ n = 1500 rev
#   F_m³ = 4e13 / 1500 = 2.6667e10 N³  →  F_m = 2987.6 N
#   L10 = C³ / F_m³ · 10⁶ = 2.7e13 / 2.6667e10 · 10⁶ = 1012.5 · 10⁶ revolutions
HAND_FM_N = (4e13 / 1500) ** (1 / 3)
HAND_L10_REV = 1012.5e6


def test_cubic_mean_load_and_l10_match_the_hand_computed_duty_cycle():
    fm = cubic_mean_load([2000.0, 4000.0], [1000.0, 500.0])
    assert fm == pytest.approx(2987.6, abs=0.05)
    assert fm == pytest.approx(HAND_FM_N, rel=1e-12)
    assert l10_revolutions(30_000.0, fm) == pytest.approx(HAND_L10_REV, rel=1e-12)


def test_constant_load_gives_the_catalogue_formula_directly():
    # F_m of a constant load is that load: L10 = (C/F)³ 10⁶ (60 kN / 6 kN → 10³ · 10⁶)
    assert cubic_mean_load([6000.0] * 4, [1.0, 2.0, 3.0, 4.0]) == pytest.approx(6000.0, rel=1e-12)
    assert l10_revolutions(60_000.0, 6000.0) == pytest.approx(1e9, rel=1e-12)


def test_life_from_samples_counts_revolutions_per_held_interval():
    # 3 one-second intervals at 500 rev/s: 500 rev at 2 kN, 500 at 2 kN, 500 at 4 kN — the hand
    # duty cycle. The last sample closes the record and carries no interval. The sign of the load
    # and of the speed does not matter. 1500 rev in 3 s = 1.8e6 rev/h → L10 = 1.0125e9 / 1.8e6 h.
    w = 2 * math.pi * 500.0
    est = life_from_samples([0.0, 1.0, 2.0, 3.0], [2000.0, -2000.0, 4000.0, 1e9], [w, -w, w, 0.0], 30_000.0)
    assert est.mean_load_n == pytest.approx(HAND_FM_N, rel=1e-12)
    assert est.cycle_revolutions == pytest.approx(1500.0, rel=1e-12)
    assert est.l10_revolutions == pytest.approx(HAND_L10_REV, rel=1e-12)
    assert est.l10_hours == pytest.approx(HAND_L10_REV / 1.8e6, rel=1e-12)
    assert est.l10_cycles == pytest.approx(HAND_L10_REV / 1500.0, rel=1e-12)


def test_life_limits_and_refusals():
    assert math.isnan(cubic_mean_load([1000.0], [0.0]))  # no revolution: no fatigue, F_m undefined
    assert l10_revolutions(30_000.0, 0.0) == math.inf
    still = life_from_samples(np.arange(3.0), [5000.0] * 3, [0.0] * 3, 30_000.0)
    assert math.isnan(still.l10_revolutions) and still.cycle_revolutions == 0.0
    with pytest.raises(ValueError, match="dynamic_load_rating_n"):
        l10_revolutions(0.0, 1000.0)
    with pytest.raises(ValueError, match="must match"):
        cubic_mean_load([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="must not decrease"):
        life_from_samples([0.0, 2.0, 1.0], [1.0] * 3, [1.0] * 3, 1e4)

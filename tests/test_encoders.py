"""Tests of odofuse.encoders (002 source arithmetic, rollover unwrapping)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from odofuse.encoders import (
    Encoder,
    steps_to_angle,
    ticks_per_metre,
    ticks_to_angle,
    unwrap_rollover,
)


def test_002_worked_example_and_its_misprint():
    # 48 ticks/motor rev x 20.4 motor revs/wheel rev / (pi D): D = 0.08 m as printed in 002
    assert ticks_per_metre(48, 20.4, 0.08) == pytest.approx(3896.11, abs=0.005)
    # the 3246.76 printed beside it is what a 0.096 m wheel gives
    assert ticks_per_metre(48, 20.4, 0.096) == pytest.approx(3246.76, abs=0.005)
    assert ticks_per_metre(48, 20.4, 0.08) != pytest.approx(3246.76, abs=1.0)
    assert Encoder(48, 20.4).ticks_per_metre(0.08) == ticks_per_metre(48, 20.4, 0.08)


def test_ticks_to_angle_and_consistency_with_ticks_per_metre():
    assert ticks_to_angle(979.2, 48, 20.4) == pytest.approx(2 * math.pi)  # one wheel rev
    assert ticks_to_angle(979.2, 979.2) == pytest.approx(2 * math.pi)  # config form (spec)
    np.testing.assert_allclose(ticks_to_angle([0, 48, -96], 48), [0, 2 * math.pi, -4 * math.pi])
    # one metre of ticks turns a D = 0.08 m wheel by 1 / 0.04 rad
    tpm = ticks_per_metre(48, 20.4, 0.08)
    assert ticks_to_angle(tpm, 48, 20.4) * 0.04 == pytest.approx(1.0)


def test_steps_to_angle():
    assert steps_to_angle(200, 200) == pytest.approx(2 * math.pi)
    assert steps_to_angle(1600, 200, microsteps=16) == pytest.approx(math.pi)
    np.testing.assert_allclose(
        steps_to_angle(np.array([[50], [-50]]), 200), [[math.pi / 2], [-math.pi / 2]]
    )


def test_unwrap_rollover_both_directions_unsigned_16_bit():
    rng = np.random.default_rng(0)
    true = np.cumsum(rng.integers(-3000, 3000, size=500)) + 60000  # crosses 65536 and 0 repeatedly
    raw = np.mod(true, 65536)
    unwrapped, n = unwrap_rollover(raw, 65536)
    np.testing.assert_array_equal(unwrapped - unwrapped[0], true - true[0])
    assert unwrapped.dtype == np.int64
    expected = int(np.count_nonzero(np.diff(np.floor_divide(true, 65536))))
    assert n == expected and n > 2


def test_unwrap_rollover_signed_counter_and_columns():
    true = np.column_stack([np.arange(0, 200000, 7000), -np.arange(0, 200000, 7000)])
    raw = (true + 32768) % 65536 - 32768  # int16 counter
    unwrapped, n = unwrap_rollover(raw, 65536)
    np.testing.assert_array_equal(unwrapped, true)
    assert n == 2 * 3  # 200000 / 65536 -> 3 wraps per wheel, one up, one down


def test_unwrap_rollover_float_and_no_wrap():
    raw = np.array([100.5, 200.5, 10.25, 250.0, 5.0])  # 8-bit counter stored as float
    unwrapped, n = unwrap_rollover(raw, 256)
    np.testing.assert_allclose(unwrapped, [100.5, 200.5, 266.25, 250.0, 261.0])
    assert n == 3  # 200.5 -> 10.25 up, 10.25 -> 250 down, 250 -> 5 up
    smooth, n0 = unwrap_rollover(np.arange(10), 256)
    np.testing.assert_array_equal(smooth, np.arange(10))
    assert n0 == 0
    # jumps of exactly half the range are not wraps ("exceeds half the range")
    assert unwrap_rollover([0, 128, 0], 256)[1] == 0


def test_unwrap_rollover_bad_input():
    with pytest.raises(ValueError, match="rollover"):
        unwrap_rollover([1, 2], 0)
    with pytest.raises(ValueError, match="non-finite"):
        unwrap_rollover([1.0, np.nan], 256)
    with pytest.raises(ValueError, match="shape"):
        unwrap_rollover(np.zeros((2, 2, 2)), 256)


def test_encoder_to_radians():
    enc = Encoder(ticks_per_rev=979.2, rollover=65536)
    true = np.arange(0, 300000, 20000, dtype=np.int64)
    ang, n = enc.convert(true % 65536)
    np.testing.assert_allclose(ang, 2 * math.pi * true / 979.2)
    assert n == 4
    np.testing.assert_allclose(enc.to_radians(true % 65536), ang)
    np.testing.assert_allclose(Encoder(48, 20.4).to_radians([979.2]), [2 * math.pi])
    with pytest.raises(ValueError, match="ticks_per_rev"):
        Encoder(0)
    with pytest.raises(ValueError, match="rollover"):
        Encoder(100, rollover=-1)

"""The shared comparison helper (livegesture.compare): the scaled bound of docs/parity.md, NaN-safe."""

import numpy as np
import pytest

from livegesture.compare import assert_within, diff


def test_a_few_float32_ulps_near_40_pass_the_scaled_bound():
    ref = (38.0 + 0.03 * np.arange(64)).astype(np.float32)
    got = ref.copy()
    ulp = np.spacing(np.float32(40.0))
    got[40] = got[40] + 4 * ulp
    d = diff(got, ref)
    assert d.max_abs > 1e-5, d  # above the absolute bound: only the scaled one passes it
    assert d.within(1e-5), d
    assert d.index == 40 and d.compared == 64
    assert 39.0 < d.scale < 40.0


def test_below_magnitude_one_the_bound_is_absolute():
    d = diff(np.float32([0.5 + 2e-5]), np.float32([0.5]))
    assert d.scale == 1.0
    assert not d.within(1e-5) and d.within(1e-4)


def test_a_real_difference_fails_and_names_where():
    ref = np.full((2, 4), 40.0, np.float32)
    got = ref.copy()
    got[1, 2] = 40.01
    d = diff(got, ref)
    assert not d.within(1e-5)
    assert d.where == (1, 2)
    with pytest.raises(AssertionError, match=r"expert_body logits.*\[1, 2\]"):
        d.ensure(1e-5, "expert_body logits")


@pytest.mark.parametrize("side", ["got", "reference"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_on_either_side_fails_and_says_which(side, bad):
    clean = np.float32([[1.0, 2.0, 3.0]])
    broken = clean.copy()
    broken[0, 1] = bad
    d = diff(broken, clean) if side == "got" else diff(clean, broken)
    assert not d.within(1e9), d
    assert d.max_abs == float("inf")
    assert d.nonfinite.startswith(f"{side}[0, 1]"), d.nonfinite
    with pytest.raises(AssertionError, match="non-finite"):
        assert_within(broken, clean, 1.0)


def test_nan_on_both_sides_fails():
    d = diff(np.float32([np.nan]), np.float32([np.nan]))
    assert not d.within(1.0) and "both" in d.nonfinite


def test_nothing_compared_fails():
    d = diff(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32))
    assert d.compared == 0 and not d.within(1e30)
    assert "nothing compared" in d.describe()


def test_shape_mismatch_fails_without_broadcasting():
    d = diff(np.zeros((1, 3), np.float32), np.zeros((3,), np.float32))
    assert not d.within(1e30) and "shapes differ" in d.describe()
    assert not diff(np.zeros(2, np.float32), np.zeros(3, np.float32)).within(1e30)


def test_torch_tensors_are_accepted():
    torch = pytest.importorskip("torch")
    assert diff(torch.ones(3), np.ones(3, np.float32)).within(0.0)
    assert not diff(torch.tensor([float("nan")]), np.ones(1, np.float32)).within(1.0)


def test_worst_keeps_the_failure_then_the_larger_scaled_error():
    small = diff(np.float32([1.0]), np.float32([1.0]))
    big = diff(np.float32([41.0]), np.float32([40.0]))
    bad = diff(np.float32([np.nan]), np.float32([1.0]))
    assert small.worst(big) is big and big.worst(small) is big
    assert big.worst(bad) is bad and bad.worst(big) is bad

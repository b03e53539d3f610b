"""`agent_envs.arrays`' reductions: the same bits as numpy's (and torch's) own."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from agent_envs import arrays

# shapes with at least one axis of length 1 (where the reductions take their element-wise
# path) and some without
SHAPES = hnp.array_shapes(min_dims=1, max_dims=4, min_side=1, max_side=4)
SPECIAL = st.sampled_from([0.0, -0.0, np.inf, -np.inf, np.nan, 1e-308, -5e-324, 1.5])
VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64), SPECIAL)


def _same_bits(got: np.ndarray, want: np.ndarray) -> None:
    assert got.shape == want.shape and got.dtype == want.dtype
    np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64))


@settings(max_examples=300, deadline=None)
@given(a=hnp.arrays(np.float64, SHAPES, elements=VALUES), data=st.data())
def test_sum_and_mean_axis_equal_numpys_bit_for_bit(a, data):
    """Signed zeros, infinities, NaN and subnormals included: -0.0 alone on its axis sums to
    +0.0 in numpy (the identity is added), and so here."""
    axis = data.draw(st.integers(-a.ndim, a.ndim - 1))
    with np.errstate(invalid="ignore", over="ignore"):
        _same_bits(np.asarray(arrays.sum_axis(a, axis)), np.asarray(np.sum(a, axis=axis)))
        _same_bits(np.asarray(arrays.mean_axis(a, axis)), np.asarray(np.mean(a, axis=axis)))


def test_reductions_over_one_entry_return_new_arrays():
    """The element-wise path does not hand out a view of its input (callers may write)."""
    a = np.array([[[-0.0], [2.0]]])
    for reduce in (arrays.sum_axis, arrays.mean_axis):
        out = reduce(a, -1)
        out[...] = 7.0
        assert a[0, 1, 0] == 2.0 and np.signbit(a[0, 0, 0])
    assert arrays.sum_axis(np.ones((2, 1, 3), np.float32), 1).dtype == np.float32


@pytest.mark.parametrize("dtype", [np.float32, np.int64, np.uint8, np.bool_])
def test_reductions_of_other_dtypes_are_numpys_own(dtype):
    """float32 keeps its dtype on the element-wise path; integers and booleans take numpy's
    reduction itself (their sums are integers, exact beyond 2^53)."""
    a = np.array([[[-0.0], [2.5], [7.0]]]).astype(dtype)
    if dtype is np.int64:
        a[0, 1, 0] = 2**53 + 1
    for axis in (-1, 0, 1):
        for mine, theirs in ((arrays.sum_axis, np.sum), (arrays.mean_axis, np.mean)):
            got, want = np.asarray(mine(a, axis)), np.asarray(theirs(a, axis=axis))
            assert got.dtype == want.dtype
            if got.dtype.kind == "f":
                _same_bits(got.astype(np.float64), want.astype(np.float64))
            else:
                np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_reductions_on_torch_equal_torchs_own_bit_for_bit(dtype):
    torch = pytest.importorskip("torch")
    as_int = {"float64": torch.int64, "float32": torch.int32}[dtype]
    a = torch.tensor([[[-0.0], [2.5], [float("nan")]]], dtype=getattr(torch, dtype))
    for axis in (-1, 0, 1):
        for mine, theirs in ((arrays.sum_axis, torch.sum), (arrays.mean_axis, torch.mean)):
            got, want = mine(a, axis), theirs(a, dim=axis)
            assert got.dtype == want.dtype
            assert torch.equal(got.view(as_int), want.view(as_int))  # signed zeros, NaN bits
    ints = torch.tensor([[3], [4]])
    assert torch.equal(arrays.sum_axis(ints, -1), ints.sum(dim=-1))

"""The Riccati recursion split per person in a window where nothing couples the persons:
the same gains as the full recursion, and refused where a cross-person block is non-zero."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.backends.mujoco.fd_split import PersonBlocks
from pipeline.backends.mujoco.ilqr import (
    Linearisation,
    backward_pass,
    blocked_backward_pass,
    person_parts,
    separable,
)

H = 6


def _blocks() -> PersonBlocks:
    # Two persons with 3 and 2 DOFs and 2 and 1 actuators, interleaved in the model's order.
    return PersonBlocks(
        dofs=(np.array([0, 1, 4]), np.array([2, 3])),
        acts=(np.array([0, 2]), np.array([1])),
        geom_person=np.zeros(0, dtype=np.int64),
    )


def _separable_lin(rng: np.random.Generator, parts: list[tuple[np.ndarray, np.ndarray]], nx: int, na: int) -> Linearisation:
    A = np.zeros((H, nx, nx))
    B = np.zeros((H, nx, na))
    lxx = np.zeros((H + 1, nx, nx))
    luu = np.zeros((H, na, na))
    for xi, ui in parts:
        n, m = len(xi), len(ui)
        A[:, xi[:, None], xi[None, :]] = np.eye(n)[None] + 0.1 * rng.normal(size=(H, n, n))
        B[:, xi[:, None], ui[None, :]] = 0.3 * rng.normal(size=(H, n, m))
        M = rng.normal(size=(H + 1, n, n))
        lxx[:, xi[:, None], xi[None, :]] = M @ M.transpose(0, 2, 1) / n
        N = rng.normal(size=(H, m, m))
        luu[:, ui[:, None], ui[None, :]] = 0.1 * N @ N.transpose(0, 2, 1) / m
    return Linearisation(A=A, B=B, lx=rng.normal(size=(H + 1, nx)), lu=rng.normal(size=(H, na)), lxx=lxx, luu=luu)


def test_split_recursion_gives_the_full_recursions_gains() -> None:
    blocks = _blocks()
    active = np.array([2, 0, 1])  # the optimised controls, in the optimiser's order
    parts = person_parts(blocks, active)
    np.testing.assert_array_equal(parts[0][0], [0, 1, 4, 5, 6, 9])
    np.testing.assert_array_equal(parts[0][1], [0, 1])  # actuators 2 and 0 are active columns 0, 1
    np.testing.assert_array_equal(parts[1][1], [2])
    lin = _separable_lin(np.random.default_rng(4), parts, nx=10, na=3)
    assert separable(lin, parts)
    full, split = backward_pass(lin, 1e-3), blocked_backward_pass(lin, 1e-3, parts)
    assert full is not None and split is not None
    for f, s in zip(full, split, strict=True):
        np.testing.assert_allclose(np.asarray(s), np.asarray(f), rtol=1e-9, atol=1e-12)
    assert np.abs(full[0]).max() > 0.1  # non-trivial gains


@pytest.mark.parametrize("field", ["A", "B", "lxx", "luu"])
def test_one_cross_person_entry_makes_the_window_inseparable(field: str) -> None:
    parts = person_parts(_blocks(), np.arange(3))
    lin = _separable_lin(np.random.default_rng(5), parts, nx=10, na=3)
    arr = getattr(lin, field)
    x0, x1 = parts[0][0][0], parts[1][0][0]
    u0, u1 = parts[0][1][0], parts[1][1][0]
    index = {"A": (2, x0, x1), "B": (2, x1, u0), "lxx": (2, x1, x0), "luu": (2, u0, u1)}[field]
    arr[index] = 1e-12
    assert not separable(lin, parts)


def test_a_person_without_a_positive_definite_step_stops_the_split_pass() -> None:
    parts = person_parts(_blocks(), np.arange(3))
    lin = _separable_lin(np.random.default_rng(6), parts, nx=10, na=3)
    ui = parts[1][1]
    lin.luu[:, ui[:, None], ui[None, :]] -= 50.0
    assert separable(lin, parts)
    assert blocked_backward_pass(lin, 1e-3, parts) is None and backward_pass(lin, 1e-3) is None

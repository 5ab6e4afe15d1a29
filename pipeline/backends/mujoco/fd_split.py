"""Finite-difference transition Jacobians that nudge one DOF (or actuator) of every person
at once, when the persons do not touch.

``mujoco.mjd_transitionFD`` steps the model once per control, per velocity and per position
perturbation: 2·nv + nu steps of the whole scene. Two athletes who are not in contact move
independently within one step, so nudging DOF k of each of them in the same step and
reading each one's response from his own rows gives the same Jacobian from a half (a third
for three persons) of the steps; the blocks between persons are zero. It is what sparse
Jacobian estimation calls column grouping (Curtis, Powell and Reid 1974), with the persons
as the structurally independent groups.

The steps replicate ``mjd_stepFD``'s forward differences (MuJoCo's
``src/engine/engine_derivative_fd.c``): one full step at the input, controls nudged with the
position and velocity stages skipped (backwards at an upper control limit), velocities with
the position stage skipped, positions through ``mj_integratePos``; the input state (with
warm start and controls) restored in between. The only difference to a person-by-person
estimate is the constraint solver: it solves all contacts of a step together, and its
iterations stop on the joint problem, so a person's response can differ at the solver's
tolerance. Where two persons' geoms are in contact (or within contact margin), the estimate
is not separable and ``transition_fd`` returns False: the caller uses ``mjd_transitionFD``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np


@dataclass(frozen=True)
class PersonBlocks:
    """Each person's DOFs and actuators in one model, and the column groups they give.

    Fields:
        dofs: per person, its DOF indices (into ``qvel``), together all of ``0..nv-1``.
        acts: per person, its actuator indices (into ``ctrl``), together all of ``0..nu-1``.
        geom_person: (ngeom,) person index of each geom, -1 for the world (floor).
    """

    dofs: tuple[np.ndarray, ...]
    acts: tuple[np.ndarray, ...]
    geom_person: np.ndarray
    _dof_groups: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(init=False, repr=False)
    _act_groups: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        nv = sum(len(d) for d in self.dofs)
        object.__setattr__(self, "_dof_groups", _groups(self.dofs, self.dofs, nv))
        object.__setattr__(self, "_act_groups", _groups(self.acts, self.dofs, nv))

    @property
    def nv(self) -> int:
        return sum(len(d) for d in self.dofs)

    def fits(self, model: mujoco.MjModel) -> bool:
        """True when the blocks partition the model's DOFs and actuators (no activations)."""
        dofs = np.sort(np.concatenate(self.dofs)) if self.dofs else np.zeros(0)
        acts = np.sort(np.concatenate(self.acts)) if self.acts else np.zeros(0)
        return (
            len(self.dofs) > 1
            and model.na == 0
            and np.array_equal(dofs, np.arange(model.nv))
            and np.array_equal(acts, np.arange(model.nu))
            and self.geom_person.shape == (model.ngeom,)
        )


def _groups(
    cols: tuple[np.ndarray, ...], dofs: tuple[np.ndarray, ...], nv: int
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per group k (the k-th column of every person that has one): the columns nudged
    together, and the (state row, column) pairs each person's response fills."""
    out = []
    for k in range(max((len(c) for c in cols), default=0)):
        nudged, rows, where = [], [], []
        for c, d in zip(cols, dofs, strict=True):
            if k < len(c):
                nudged.append(int(c[k]))
                r = np.concatenate([d, nv + d])
                rows.append(r)
                where.append(np.full(r.size, int(c[k])))
        out.append((np.array(nudged, dtype=np.int64), np.concatenate(rows), np.concatenate(where)))
    return out


def persons_in_contact(data: mujoco.MjData, geom_person: np.ndarray) -> bool:
    """True when the current contacts (``data.contact``, from the last forward pass) include a
    pair of geoms of two different persons."""
    if data.ncon == 0:
        return False
    p = geom_person[np.asarray(data.contact.geom[: data.ncon])]
    return bool(np.any((p[:, 0] >= 0) & (p[:, 1] >= 0) & (p[:, 0] != p[:, 1])))


_RESTORE = int(mujoco.mjtState.mjSTATE_FULLPHYSICS | mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_WARMSTART)


def transition_fd(
    model: mujoco.MjModel, data: mujoco.MjData, eps: float, blocks: PersonBlocks, A: np.ndarray, B: np.ndarray
) -> bool:
    """Forward-difference A (2nv, 2nv) and B (2nv, nu) of one ``mj_step`` from ``data``'s state
    and controls, nudging one DOF or actuator of every person per step (module docstring).

    Returns False, with ``data`` restored and A, B untouched, when two persons' geoms are in
    contact at the input state, the model's integrator is RK4 or the blocks do not fit the
    model; the caller then uses ``mujoco.mjd_transitionFD``. ``eps`` > 0: the nudge.
    """
    if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 or not blocks.fits(model):
        return False
    nv = model.nv
    saved = np.empty(mujoco.mj_stateSize(model, _RESTORE))
    mujoco.mj_getState(model, data, saved, _RESTORE)
    ctrl = data.ctrl.copy()

    def step(skip: mujoco.mjtStage) -> None:
        mujoco.mj_forwardSkip(model, data, skip, 1)
        if model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER:
            mujoco.mj_Euler(model, data)
        else:
            mujoco.mj_implicit(model, data)

    step(mujoco.mjtStage.mjSTAGE_NONE)
    if persons_in_contact(data, blocks.geom_person):
        mujoco.mj_setState(model, data, saved, _RESTORE)
        return False
    q_next, v_next = data.qpos.copy(), data.qvel.copy()
    ds = np.empty(2 * nv)
    inv_eps = 1.0 / eps

    def response() -> np.ndarray:
        """(2nv,) (next state - nominal next state) / eps of the step just taken; restores the input."""
        mujoco.mj_differentiatePos(model, ds[:nv], eps, q_next, data.qpos)
        np.subtract(data.qvel, v_next, out=ds[nv:])
        ds[nv:] *= inv_eps  # as mjd_stepFD: times 1/eps, not divided by eps (the same rounding)
        mujoco.mj_setState(model, data, saved, _RESTORE)
        return ds

    mujoco.mj_setState(model, data, saved, _RESTORE)
    A[:] = 0.0
    B[:] = 0.0
    # Controls: nudged forward, or backward at the upper end of a control range (as mjd_stepFD).
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    limited = model.actuator_ctrllimited.astype(bool)
    fwd = ~limited | ((ctrl >= lo) & (ctrl + eps <= hi))
    back = ~limited | ((ctrl - eps >= lo) & (ctrl <= hi))
    sign = np.where(fwd, 1.0, np.where(back, -1.0, 0.0))
    for nudged, rows, cols in blocks._act_groups:
        data.ctrl[nudged] = ctrl[nudged] + sign[nudged] * eps
        step(mujoco.mjtStage.mjSTAGE_VEL)
        d = response()
        B[rows, cols] = d[rows] * sign[cols]
    for nudged, rows, cols in blocks._dof_groups:
        data.qvel[nudged] += eps
        step(mujoco.mjtStage.mjSTAGE_POS)
        d = response()
        A[rows, nv + cols] = d[rows]
    dpos = np.zeros(nv)
    for nudged, rows, cols in blocks._dof_groups:
        dpos[:] = 0.0
        dpos[nudged] = 1.0
        mujoco.mj_integratePos(model, data.qpos, dpos, eps)
        step(mujoco.mjtStage.mjSTAGE_NONE)
        d = response()
        A[rows, cols] = d[rows]
    return True

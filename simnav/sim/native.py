"""MuJoCo's ``mj_step`` called from compiled (Numba) code, for the stretches of the motor ramp, and a robot-only
shadow model that runs most of them.

While the motor controller ramps towards a command, the control changes every motor period (every physics step
at the default 10 ms), so each stretch is one ``mj_step`` call. Made from Python, each costs the binding's call
and the ramp's bookkeeping; :func:`ramp_steps` runs those stretches in one compiled call instead, calling the
functions of the MuJoCo library that the ``mujoco`` package loaded through their C addresses. The controls are the
same doubles (the ramp's arithmetic is the same).

The shadow (:func:`robot_shadow`): while MuJoCo's collision detection is off, nothing but the robot's own tree
enters its dynamics (the people, other robots and doors are mocap bodies, everything else is static and there are
no constraints), yet each step of the scene also poses every mocap body and its geoms. A model of the robot
alone, compiled from the same robot description and options, steps the same state to the same state, to the bit
(checked when it is made, else there is no shadow), in about half the time. :func:`ramp_steps` runs all but the
last stretch of a ramp in it, then copies its state (time, positions, velocities, warm start, controls) back and
runs the last stretch in the scene, so that everything computed from the state (poses, forces, ...) is also what
the scene's own steps would have left.

MuJoCo times the stages of every step through its timer callback ``mjcb_time`` (a clock reading at each stage's
start and end, ~30 per step), which costs more than a whole step of the shadow here. :func:`quiet_timers` sets a
callback that reads no clock while the simulator steps (:func:`restore_timers` puts the previous one back): the
stage timers in ``MjData.timer`` then record 0 s, and nothing else changes (the timers feed nothing).

The addresses come from the library file (found next to the ``mujoco`` package, opened again: the loader returns
the library already in the process); :data:`MJ_STEP` is 0 where it is not found, and the caller then steps from
Python. These functions report errors through MuJoCo's error callback, which the Python bindings turn into
exceptions: the compiled loop is used only where the caller has ruled them out (collision detection off, so no
contact can fill the arena).
"""

from __future__ import annotations

import ctypes
import glob
import os

import mujoco
import numpy as np
from llvmlite import ir
from numba import cfunc, njit, types
from numba.core.extending import intrinsic

STATE = int(mujoco.mjtState.mjSTATE_FULLPHYSICS | mujoco.mjtState.mjSTATE_WARMSTART | mujoco.mjtState.mjSTATE_CTRL)
"""The state a shadow takes over and hands back: time, positions, velocities, activations (and the other
physics state), the warm start of the accelerations and the controls."""
SELF_CHECKS = 8  # random states (of SELF_CHECK_STEPS steps each) a shadow must follow to the bit
SELF_CHECK_STEPS = 12


def _addresses(*names: str) -> tuple[int, ...]:
    """Addresses of the named functions of the MuJoCo library of the ``mujoco`` package and of its ``mjcb_time``
    variable (last), or zeros if not found."""
    folder = os.path.dirname(mujoco.__file__)
    for pattern in ("libmujoco.so*", "libmujoco*.dylib", "mujoco.dll"):
        for path in sorted(glob.glob(os.path.join(folder, pattern))):
            try:
                lib = ctypes.CDLL(path)
                functions = tuple(ctypes.cast(getattr(lib, name), ctypes.c_void_p).value or 0 for name in names)
                return (*functions, ctypes.addressof(ctypes.c_void_p.in_dll(lib, "mjcb_time")))
            except (OSError, AttributeError, ValueError):
                continue
    return (0,) * (len(names) + 1)


@cfunc(types.float64())
def _no_time() -> float:
    """A timer callback for MuJoCo that reads no clock (its stage timers then record 0 s)."""
    return 0.0


MJ_STEP, MJ_GET_STATE, MJ_SET_STATE, MJCB_TIME = _addresses("mj_step", "mj_getState", "mj_setState")
"""Addresses of MuJoCo's ``mj_step(const mjModel*, mjData*)``, ``mj_getState(const mjModel*, const mjData*,
mjtNum* state, int sig)`` and ``mj_setState(const mjModel*, mjData*, const mjtNum* state, int sig)``; 0 when
unavailable."""
NATIVE = MJ_STEP != 0 and MJ_GET_STATE != 0 and MJ_SET_STATE != 0
"""Whether :func:`ramp_steps` can run (else the caller steps from Python)."""
_TIMER_SLOT = ctypes.c_void_p.from_address(MJCB_TIME) if MJCB_TIME else None
_NO_TIME = _no_time.address


def quiet_timers() -> int | None:
    """Set MuJoCo's timer callback to one that reads no clock (its stage timers then record 0 s, and every step
    saves the clock readings); returns what to give :func:`restore_timers`."""
    if _TIMER_SLOT is None:
        return None
    previous = _TIMER_SLOT.value
    _TIMER_SLOT.value = _NO_TIME
    return previous


def restore_timers(previous: int | None) -> None:
    """Put back the timer callback that :func:`quiet_timers` replaced."""
    if _TIMER_SLOT is not None:
        _TIMER_SLOT.value = previous


FUNCTIONS = np.array([MJ_STEP, MJ_GET_STATE, MJ_SET_STATE], dtype=np.int64)
"""What :func:`ramp_steps` calls: ``mj_step``, ``mj_getState`` and ``mj_setState``."""


@intrinsic
def _call_step(typingctx, fn, model, data):
    """Call the C function at address ``fn`` as ``void fn(void* model, void* data)`` (addresses as integers)."""
    sig = types.void(types.int64, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        ptr = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [ptr, ptr])
        callee = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(callee, [builder.inttoptr(args[1], ptr), builder.inttoptr(args[2], ptr)])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _call_state(typingctx, fn, model, data, state, spec):
    """Call the C function at address ``fn`` as ``void fn(void* model, void* data, double* state, int spec)``
    (``mj_getState``, ``mj_setState``; addresses as integers)."""
    sig = types.void(types.int64, types.int64, types.int64, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        ptr = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [ptr, ptr, ir.DoubleType().as_pointer(), ir.IntType(32)])
        callee = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(callee, [builder.inttoptr(args[1], ptr), builder.inttoptr(args[2], ptr),
                              builder.inttoptr(args[3], ir.DoubleType().as_pointer()),
                              builder.trunc(args[4], ir.IntType(32))])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, error_model="numpy")
def _ramped(x: float, target: float, limit: float) -> float:
    """``x`` moved towards ``target`` by at most ``limit`` (as :func:`simnav.sim.simulator._ramped`)."""
    d = target - x
    return x + (limit if d > limit else -limit if d < -limit else d)


@njit(cache=True, error_model="numpy")
def _hand_over(functions: np.ndarray, model_from: int, data_from: int, model_to: int, data_to: int,
               state: np.ndarray) -> None:
    """Copy the STATE of one data (of its model) to another through ``state`` (room for it)."""
    _call_state(functions[1], model_from, data_from, state.ctypes.data, STATE)
    _call_state(functions[2], model_to, data_to, state.ctypes.data, STATE)


@njit(cache=True, error_model="numpy")
def ramp_steps(functions: np.ndarray, model: int, data: int, ctrl: np.ndarray, base_qpos: np.ndarray,
               shadow_model: int, shadow_data: int, shadow_ctrl: np.ndarray, shadow_qpos: np.ndarray,
               state: np.ndarray, k: int, first: int, limit: int, motor: int, v: float, w: float, v_target: float,
               w_target: float, dv_max: float, dw_max: float, switch_at: int, v_next: float, w_next: float,
               ring_steps: np.ndarray, ring_poses: np.ndarray, at: int) -> tuple[int, float, float, int, bool]:
    """A stretch of ``first`` physics steps from step ``k`` with the controls as they are (none for 0), then the
    motor ramp's stretches: while the step is on a motor period, a whole period fits before step ``limit`` and
    (v, w) has not reached the target, (v, w) moves towards (``v_target``, ``w_target``) by at most (``dv_max``,
    ``dw_max``), goes to the controls (forward and yaw), and ``motor`` physics steps run.

    At step ``switch_at`` (a queued command applying there; beyond ``limit`` for none) the target becomes
    (``v_next``, ``w_next``) if (v, w) is still ramping towards the old one and has not reached the new one (the
    stretch from there is then the one the stepping loop runs after the command applies); else the stretches
    stop there.

    Args:
        functions: the addresses of ``mj_step``, ``mj_getState`` and ``mj_setState`` (:data:`FUNCTIONS`).
        model, data: the scene's addresses; ctrl (nu,) and base_qpos (3,): views of its controls and of the base's
            x, y, yaw.
        shadow_model, shadow_data, shadow_ctrl, shadow_qpos: the same of a robot-only shadow
            (:func:`robot_shadow`), addresses 0 for none; state: room for its STATE.
        ring_steps, ring_poses: (R,) and (R, 3) rings of stretch ends: each stretch's end step and the base pose
            (x, y, yaw) after it go to entry ``at``, ``at + 1``, ... (modulo R); at most R stretches run.

    Returns:
        The step reached, the ramp's (v, w), the number of stretches run and whether the target switched.
    """
    size = ring_steps.shape[0]
    # how many stretches run
    count, kk, vv, ww, vt, wt = (1, k + first, v, w, v_target, w_target) if first > 0 else \
        (0, k, v, w, v_target, w_target)
    while count < size and kk % motor == 0 and kk + motor <= limit and (vt != vv or wt != ww):
        if kk == switch_at:
            if v_next == vv and w_next == ww:
                break
            vt, wt = v_next, w_next
        vv, ww = _ramped(vv, vt, dv_max), _ramped(ww, wt, dw_max)
        kk += motor
        count += 1
    switched = False
    # all but the last in the shadow (when there is one), the last in the scene
    shadowed = count - 1 if shadow_model != 0 else 0
    if shadowed > 0:
        _hand_over(functions, model, data, shadow_model, shadow_data, state)
    for i in range(count):
        given = i == 0 and first > 0  # the first stretch, with the controls as they are
        steps = first if given else motor
        if not given:
            if k == switch_at:
                v_target, w_target, switched = v_next, w_next, True
            v, w = _ramped(v, v_target, dv_max), _ramped(w, w_target, dw_max)
        j = (at + i) % size
        if i < shadowed:
            if not given:
                shadow_ctrl[0], shadow_ctrl[2] = v, w  # (ctrl[1], the lateral speed, stays 0)
            for _ in range(steps):
                _call_step(functions[0], shadow_model, shadow_data)
            ring_poses[j, 0], ring_poses[j, 1], ring_poses[j, 2] = shadow_qpos[0], shadow_qpos[1], shadow_qpos[2]
        else:
            if i == shadowed and shadowed > 0:
                _hand_over(functions, shadow_model, shadow_data, model, data, state)
            if not given:
                ctrl[0], ctrl[2] = v, w
            for _ in range(steps):
                _call_step(functions[0], model, data)
            ring_poses[j, 0], ring_poses[j, 1], ring_poses[j, 2] = base_qpos[0], base_qpos[1], base_qpos[2]
        k += steps
        ring_steps[j] = k
    return k, v, w, count, switched


def robot_shadow(spec_of_robot, model: mujoco.MjModel, qpos_adr: np.ndarray, dof_adr: np.ndarray
                 ) -> tuple[mujoco.MjModel, mujoco.MjData] | None:
    """A model of the robot alone that steps like ``model`` (collision detection off), and its data, or None.

    Args:
        spec_of_robot: builds the robot alone: ``spec_of_robot() -> mujoco.MjSpec`` (with the scene's options).
        model: the scene.
        qpos_adr, dof_adr: (3,) addresses of the robot's x, y, yaw joints in the scene.

    Returns:
        None when the scene has state beyond the robot's joints (other joints, activations, ...), the states
        differ in size, or the shadow fails to follow the scene to the bit from random states and controls.
    """
    if not NATIVE or model.nq != 3 or model.nv != 3 or not np.array_equal(qpos_adr, [0, 1, 2]) \
            or not np.array_equal(dof_adr, [0, 1, 2]):
        return None
    spec = spec_of_robot()
    for geom in list(spec.geoms):  # the shadow never collides
        spec.delete(geom)
    for light in list(spec.lights):
        spec.delete(light)
    shadow = spec.compile()
    shadow.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    if mujoco.mj_stateSize(shadow, STATE) != mujoco.mj_stateSize(model, STATE) or shadow.nu != model.nu:
        return None
    shadow_data = mujoco.MjData(shadow)
    return (shadow, shadow_data) if _follows(model, shadow, shadow_data) else None


def _follows(model: mujoco.MjModel, shadow: mujoco.MjModel, shadow_data: mujoco.MjData) -> bool:
    """Whether ``shadow`` steps random states of ``model`` (collision detection off) to the same states, to the
    bit."""
    rng = np.random.default_rng(0)
    data = mujoco.MjData(model)
    flags = model.opt.disableflags
    model.opt.disableflags = flags | mujoco.mjtDisableBit.mjDSBL_CONTACT
    size = mujoco.mj_stateSize(model, STATE)
    state, after, shadow_after = np.empty(size), np.empty(size), np.empty(size)
    try:
        for _ in range(SELF_CHECKS):
            mujoco.mj_resetData(model, data)
            data.time = rng.uniform(0.0, 1000.0)
            data.qpos[:] = rng.uniform(-20.0, 20.0, 3)
            data.qvel[:] = rng.uniform(-2.0, 2.0, 3)
            data.qacc_warmstart[:] = rng.uniform(-2.0, 2.0, 3)
            mujoco.mj_getState(model, data, state, STATE)
            mujoco.mj_setState(shadow, shadow_data, state, STATE)
            for _ in range(SELF_CHECK_STEPS):
                data.ctrl[:] = shadow_data.ctrl[:] = rng.uniform(-1.5, 1.5, model.nu) * [1.0, 0.0, 1.0][:model.nu]
                mujoco.mj_step(model, data)
                mujoco.mj_step(shadow, shadow_data)
                mujoco.mj_getState(model, data, after, STATE)
                mujoco.mj_getState(shadow, shadow_data, shadow_after, STATE)
                if not (np.array_equal(after, shadow_after) and np.array_equal(data.qacc, shadow_data.qacc)):
                    return False
    finally:
        model.opt.disableflags = flags
    return True

"""MuJoCo's ``mj_step`` called from compiled (Numba) code, for the stretches of the motor ramp.

While the motor controller ramps towards a command, the control changes every motor period (every physics step
at the default 10 ms), so each stretch is one ``mj_step`` call. Made from Python, each costs the binding's call
and the ramp's bookkeeping; :func:`ramp_steps` runs those stretches in one compiled call instead, calling
``mj_step`` of the MuJoCo library that the ``mujoco`` package loaded through its C address. The controls are the
same doubles (the ramp's arithmetic is the same), so the physics and the poses are identical to the bit.

The address comes from that library file (found next to the ``mujoco`` package, opened again: the loader returns
the library already in the process); :data:`MJ_STEP` is 0 where it is not found, and the caller then steps from
Python. ``mj_step`` reports errors through MuJoCo's error callback, which the Python bindings turn into
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
from numba import njit, types
from numba.core.extending import intrinsic


def _mj_step_address() -> int:
    """Address of ``mj_step`` in the MuJoCo library of the ``mujoco`` package, or 0 if not found."""
    folder = os.path.dirname(mujoco.__file__)
    for name in ("libmujoco.so*", "libmujoco*.dylib", "mujoco.dll"):
        for path in sorted(glob.glob(os.path.join(folder, name))):
            try:
                return ctypes.cast(ctypes.CDLL(path).mj_step, ctypes.c_void_p).value or 0
            except (OSError, AttributeError):
                continue
    return 0


MJ_STEP = _mj_step_address()
"""Address of MuJoCo's ``void mj_step(const mjModel*, mjData*)``; 0 when unavailable."""


@intrinsic
def _call_step(typingctx, fn, model, data):
    """Call the C function at address ``fn`` as ``void fn(void* model, void* data)`` (addresses as integers)."""
    sig = types.void(types.intp, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        ptr = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [ptr, ptr])
        callee = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(callee, [builder.inttoptr(args[1], ptr), builder.inttoptr(args[2], ptr)])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, error_model="numpy")
def _ramped(x: float, target: float, limit: float) -> float:
    """``x`` moved towards ``target`` by at most ``limit`` (as :func:`simnav.sim.simulator._ramped`)."""
    d = target - x
    return x + (limit if d > limit else -limit if d < -limit else d)


@njit(cache=True, error_model="numpy")
def ramp_steps(step_fn: int, model: int, data: int, k: int, limit: int, motor: int, v: float, w: float,
               v_target: float, w_target: float, dv_max: float, dw_max: float, ctrl: np.ndarray,
               base_qpos: np.ndarray, steps_out: np.ndarray, poses_out: np.ndarray) -> tuple[int, float, float, int]:
    """The motor ramp's stretches from physics step ``k``: while ``k`` is on a motor period, a whole period fits
    before step ``limit`` and (v, w) has not reached the target, (v, w) moves towards (``v_target``,
    ``w_target``) by at most (``dv_max``, ``dw_max``), goes to ``ctrl[0]``, ``ctrl[2]``, and ``motor`` physics
    steps run (``mj_step`` at ``step_fn`` on the ``model`` and ``data`` addresses).

    After each stretch its end step and the (3,) ``base_qpos`` (x, y, yaw; a view of the data) are written to
    ``steps_out`` (S,) and ``poses_out`` (S, 3); at most S stretches run.

    Returns:
        The step reached, the ramp's (v, w) and the number of stretches run.
    """
    count = 0
    while (count < steps_out.shape[0] and k % motor == 0 and k + motor <= limit
           and (v_target != v or w_target != w)):
        v, w = _ramped(v, v_target, dv_max), _ramped(w, w_target, dw_max)
        ctrl[0], ctrl[2] = v, w  # (ctrl[1], the lateral speed, stays 0)
        for _ in range(motor):
            _call_step(step_fn, model, data)
        k += motor
        steps_out[count] = k
        poses_out[count, 0], poses_out[count, 1], poses_out[count, 2] = base_qpos[0], base_qpos[1], base_qpos[2]
        count += 1
    return k, v, w, count

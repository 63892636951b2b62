"""The per-step packing of an MPC step in C (`csrc/step_pack.c`): the warm start's re-sampling (`ShiftedGuess`), the
bounds of point and flat feet (`BoundsTemplate`, `CompiledMeasuredBounds`), the sources of the multipliers' shift
(`ocp/multipliers.py`, flat feet's dual warm start) and the swing feet's v_z references (`SwingVelocity`); and
(`csrc/step_prepare.c`, `csrc/step_feet.c`) a whole step's data preparation and its plan's unpacking
(`control/compiled_step.py`), and (`csrc/delay_ticks.c`) the delay prediction's tick inputs (`control/delay_ticks.py`).

Each C function is the NumPy code it replaces, operation for operation and compiled without fused multiply-adds, so
results are the same bit for bit (tests/control/test_step_packing.py, tests/ocp/test_bounds_template.py,
tests/ocp/test_multipliers.py). Why C: right after the solver's call the
interpreter's caches are cold and each of the step's ~250 small NumPy calls costs 2-4 us; one C call replaces 5-20
of them. The library is shipped source, compiled once per machine into the cache (`native.build_native`); without
a compiler `library()` is None and the callers keep their NumPy code (the same results, slower).
"""

from __future__ import annotations

import ctypes
import warnings

import numpy as np

from wbmpc.solvers.codegen import CodegenConfig, CompileError
from wbmpc.solvers.native import build_native

_libraries: dict[tuple, ctypes.CDLL | None] = {}


def library(config: CodegenConfig | None = None) -> ctypes.CDLL | None:
    """The compiled packer (built on first use, one per process and compiler), or None where it cannot be built
    (a RuntimeWarning says why once; the callers then run their NumPy code)."""
    config = config or CodegenConfig()
    key = (config.compiler, config.cache_dir)
    if key not in _libraries:
        try:
            # -O2 -ffp-contract=off: no fused multiply-adds, the NumPy arithmetic bit for bit (and no -march=native:
            # nothing here needs it)
            sources = ("step_pack.c", "step_prepare.c", "step_feet.c", "delay_ticks.c")
            report = build_native("step_pack", sources, config, ("-O2", "-ffp-contract=off"))
            lib = ctypes.CDLL(str(report.library))
        except (CompileError, OSError) as exc:
            warnings.warn(f"the compiled step packer is unavailable, packing with NumPy (slower): {exc}",
                          RuntimeWarning, stacklevel=2)
            lib = None
        if lib is not None:
            pointer = ctypes.c_void_p
            lib.wbsp_shift.argtypes = [ctypes.c_int, pointer, ctypes.c_int, pointer, ctypes.c_int, pointer,
                                       ctypes.c_int, pointer, pointer, pointer, pointer, pointer, ctypes.c_int,
                                       pointer, pointer, pointer]
            lib.wbsp_bounds_start.argtypes = [pointer, ctypes.c_int, pointer, pointer, pointer, pointer, ctypes.c_int,
                                              pointer, pointer, ctypes.c_int, ctypes.c_int, pointer]
            lib.wbsp_bounds_measured.argtypes = [pointer] * 6 + [ctypes.c_int, ctypes.c_int]
            lib.wbsp_swing_vz.argtypes = [ctypes.c_int, pointer] + [ctypes.c_double] * 4 + [pointer]
            lib.wbsp_dual_sources.argtypes = [ctypes.c_int, pointer, ctypes.c_int, ctypes.c_double] + [pointer] * 6 + \
                [ctypes.c_int, ctypes.c_int] + [pointer] * 5
            lib.wbsp_dual_sources_at.argtypes = [ctypes.c_int, pointer, pointer, ctypes.c_int, ctypes.c_double] + \
                [pointer] * 6 + [ctypes.c_int, ctypes.c_int] + [pointer] * 5
            lib.wbsp_bound_kind.argtypes = [ctypes.c_int, pointer, pointer, pointer]
            lib.wbsp_dual_shift.argtypes = [ctypes.c_int] + [pointer] * 8
            lib.wbsp_prepare.argtypes = [pointer, pointer]  # (control/compiled_step.py)
            lib.wbsp_sole_wrenches.argtypes = [ctypes.c_int64, pointer, ctypes.c_int64, pointer] + \
                [ctypes.c_int64] * 2 + [pointer] * 3 + [ctypes.c_int64] * 2 + [pointer] * 6
            lib.wbsp_tick_count.argtypes, lib.wbsp_tick_count.restype = [ctypes.c_double] * 3, ctypes.c_int64
            lib.wbsp_tick_inputs.argtypes = [ctypes.c_double] * 4 + [ctypes.c_int64] * 3 + [ctypes.c_double] + \
                [pointer, ctypes.c_int64] * 4 + [pointer, pointer, ctypes.c_int64] + [pointer] * 5  # (delay_ticks.py)
            lib.wbsp_ticks_run.argtypes = [pointer] + [ctypes.c_int64] * 4 + [pointer] * 16
            lib.wbsp_unpack.argtypes = [pointer, pointer, pointer, pointer, ctypes.c_int64, ctypes.c_int64]
        _libraries[key] = lib
    return _libraries[key]


class SwingVelocity:
    """`SwingProfile.vertical_velocity(progress, swing_duration_s)` for progress arrays of one shape, in one C call
    with the packer `lib` (inputs and output kept: their addresses taken once), else the profile's NumPy code."""

    def __init__(self, profile, lib: ctypes.CDLL | None, shape: tuple[int, ...]):
        self._profile, self._lib = profile, lib
        self._progress, self._out = np.zeros(shape), np.zeros(shape)
        self._addresses = (self._progress.ctypes.data, self._out.ctypes.data)

    def __call__(self, progress: np.ndarray, swing_duration_s: float) -> np.ndarray:
        profile = self._profile
        if self._lib is None or np.shape(progress) != self._out.shape:
            return profile.vertical_velocity(progress, swing_duration_s)
        piece_s = swing_duration_s / 2  # (the profile's arithmetic, term by term)
        self._progress[...] = progress
        self._lib.wbsp_swing_vz(self._out.size, self._addresses[0], piece_s, profile.apex_height_m,
                                profile.liftoff_velocity_m_s * piece_s, profile.touchdown_velocity_m_s * piece_s,
                                self._addresses[1])
        return self._out.copy()

"""simnav: simulation-in-the-loop range-sensing navigation.

MuJoCo simulates prism-modelled wheeled robots in office worlds with walking people; simulated lidars and
RGB-D cameras feed range-flow odometry and the 3D-PTG reactive navigator. See README.md for the CLI.
"""

import ctypes.util
import logging
import os

# Headless rendering through EGL; without an EGL library, MuJoCo's GL is disabled (it would fail at import) and
# depth cameras fall back to ray casting. Must precede any mujoco import.
os.environ.setdefault("MUJOCO_GL", "egl" if ctypes.util.find_library("EGL") else "disable")
# Software rendering (Mesa's llvmpipe, where there is no GPU) rasterises in the thread that renders instead of in
# helper threads: as fast for the small images of simulated cameras, never oversubscribes the cores of parallel
# workers, and keeps clear of the heap corruption that crashed workers in llvmpipe's threaded readback (README,
# batch runs). Ignored by GPU drivers; set LP_NUM_THREADS yourself to choose otherwise.
os.environ.setdefault("LP_NUM_THREADS", "0")

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

# Gymnasium ids (simnav/OfficeNav-v0, ...): registered now if gymnasium is loaded, else right after it loads
from simnav.env.registration import register_when_gymnasium_loads  # noqa: E402

register_when_gymnasium_loads()

"""simnav: simulation-in-the-loop range-sensing navigation.

MuJoCo simulates prism-modelled wheeled robots in office worlds with walking people; simulated lidars and
RGB-D cameras feed range-flow odometry and the 3D-PTG reactive navigator. See README.md for the CLI.
"""

import logging
import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede any mujoco import

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

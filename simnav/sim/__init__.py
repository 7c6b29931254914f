"""The MuJoCo simulator: scene assembly, stepping, ground truth, contacts and the simulated robot interface."""

from simnav.sim.config import SimConfig
from simnav.sim.robot import SimRobot
from simnav.sim.simulator import Simulator

__all__ = ["SimConfig", "SimRobot", "Simulator"]

"""The simulated robot behind :class:`simnav.robot.RobotInterface`."""

from __future__ import annotations

from simnav.sensors.readings import Reading
from simnav.sim.simulator import Simulator


class SimRobot:
    """Adapter giving a :class:`Simulator` the robot interface used by odometry and the navigator.

    ``wait_next_period`` advances the simulation by one control period with the last command sent.
    """

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self._command = (0.0, 0.0)
        self._inbox: list[Reading] = []

    @property
    def control_period_s(self) -> float:
        return self.sim.config.control_dt_s

    def now_s(self) -> float:
        return self.sim.time_s

    def send_velocity(self, v_m_s: float, w_rad_s: float) -> None:
        self._command = (float(v_m_s), float(w_rad_s))

    def poll_readings(self) -> list[Reading]:
        out, self._inbox = self._inbox, []
        return out

    def wait_next_period(self) -> None:
        self._inbox += self.sim.step(*self._command)

    def stop(self) -> None:
        self._command = (0.0, 0.0)

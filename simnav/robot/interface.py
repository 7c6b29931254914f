"""The one robot interface that the odometries and the navigator use, in simulation and on real hardware.

A control loop reads the readings that arrived since its last call, decides a velocity and sends it, then
waits for the next control period::

    while running:
        for reading in robot.poll_readings():
            ...                                   # odometry, obstacle points
        robot.send_velocity(v_m_s, w_rad_s)
        robot.wait_next_period()                  # sim: advance physics; hardware: sleep until the next tick
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from simnav.sensors.readings import Reading


@runtime_checkable
class RobotInterface(Protocol):
    """A differential-drive robot with sensors (simulated or real)."""

    @property
    def control_period_s(self) -> float:
        """Period of the control loop, s."""
        ...

    def now_s(self) -> float:
        """Current time on the robot's clock (simulation time in sim), s."""
        ...

    def send_velocity(self, v_m_s: float, w_rad_s: float) -> None:
        """Command a forward speed (m/s, base x) and a yaw rate (rad/s, counter-clockwise)."""
        ...

    def poll_readings(self) -> list[Reading]:
        """Readings that became available since the previous call, oldest first (each carries its stamp)."""
        ...

    def wait_next_period(self) -> None:
        """Block (hardware) or advance the simulation (sim) until the next control period starts."""
        ...

    def stop(self) -> None:
        """Command zero velocity."""
        ...

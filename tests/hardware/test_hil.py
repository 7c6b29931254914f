"""Hardware in the loop on the virtual bus: the simulator's robot moves by what the (emulated) motors measure, the
wheel encoders are the servos' positions, and a mission reaches its target; plus one clear error per misuse."""

from __future__ import annotations

import pytest

from simnav.errors import SimnavError
from simnav.hardware import HardwareError, HilRobot, hardware_in_the_loop
from simnav.mission.mission import MissionSettings, mission_robot, run_mission
from simnav.robot import load_robot
from simnav.sensors.readings import WheelTicks
from simnav.sim import SimConfig, Simulator
from tests.conftest import box_room_spec
from tests.hardware.conftest import minibot

HIL = ["hardware.reconnect_attempts=3"]  # rides through a status packet lost on a loaded machine


def test_a_robot_without_hardware_block_is_one_clear_error():
    with pytest.raises(SimnavError, match="robot 'giraff' has no 'hardware' block"):
        with hardware_in_the_loop("virtual", load_robot("giraff")):
            pass


def test_a_bad_port_is_one_clear_error():
    with pytest.raises(HardwareError, match="cannot open the Dynamixel port '/dev/no-such-port'"):
        with hardware_in_the_loop("/dev/no-such-port", minibot()):
            pass


def test_time_scale_is_for_the_virtual_bus_only():
    with pytest.raises(SimnavError, match="virtual bus only"):
        with hardware_in_the_loop("/dev/ttyUSB0", minibot(), time_scale=2.0):
            pass


@pytest.fixture(scope="module")
def sim_factory():
    sims = []

    def make(control_dt_s: float = 0.05) -> Simulator:
        sims.append(Simulator(box_room_spec(), minibot(), SimConfig(control_dt_s=control_dt_s)))
        return sims[-1]

    yield make
    for sim in sims:
        sim.close()


def test_the_simulator_period_must_be_a_whole_number_of_bridge_periods(sim_factory):
    with hardware_in_the_loop("virtual", minibot()) as factory:
        with pytest.raises(SimnavError, match=r"control_dt_s=0.03 s must be a whole multiple of the bridge period"):
            factory(sim_factory(0.03))


def test_the_base_moves_by_the_measured_wheels_and_the_encoders_are_the_servos(sim_factory):
    sim = sim_factory(0.05)
    with hardware_in_the_loop("virtual", minibot(*HIL), time_scale=2.0) as factory:
        robot = factory(sim)
        assert isinstance(robot, HilRobot) and robot.cycles_per_step == 2 and robot.control_period_s == 0.05
        ticks = []
        for _ in range(30):
            robot.send_velocity(0.15, 0.0)
            robot.wait_next_period()
            ticks += [r for r in robot.poll_readings() if isinstance(r, WheelTicks)]
        v_sim, w_sim = sim.base_velocity()
        assert v_sim == pytest.approx(0.15, abs=0.01) and w_sim == pytest.approx(0.0, abs=0.05)
        servo_ticks = robot.wheel_ticks
        robot.close()
    assert ticks and all(t.ticks_per_rev == 4096 for t in ticks)
    lefts = [t.left_ticks for t in ticks]
    assert lefts == sorted(lefts) and lefts[-1] > 1000
    assert abs(lefts[-1] - servo_ticks[0]) < 200  # the last reading is at most a few cycles old


@pytest.mark.slow
def test_a_mission_on_the_virtual_bus_reaches_its_target():
    robot = minibot(*HIL)
    settings = MissionSettings(targets=1, seed=2, pose_source="wheels", sim=SimConfig(pedestrians=0, wanderers=0))
    with hardware_in_the_loop("virtual", robot, time_scale=2.0) as factory:
        made = []
        report = run_mission(box_room_spec(), mission_robot(robot, settings), settings,
                             robot_factory=lambda sim: made.append(factory(sim)) or made[-1])
    assert report.targets_reached == 1 and report.minor_incidents["total"] == 0
    assert made[0].bridge.stats.cycles > 100 and report.odometry["final_error_m"] < 0.3

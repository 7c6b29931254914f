"""The robot YAML's hardware block: product defaults, and one clear error per bad field."""

from __future__ import annotations

import typing

import pytest

from simnav.errors import ConfigError
from simnav.hardware import control_table as ct
from simnav.robot import load_robot
from simnav.robot.spec import DynamixelModel, Hardware


def test_minibot_is_a_turtlebot3_like_base():
    hw = load_robot("minibot").hardware
    assert (hw.left_id, hw.right_id, hw.reverse_left, hw.reverse_right) == (1, 2, False, True)
    assert hw.baud_rate == 1_000_000 and hw.model == "XL430-W250" and hw.watchdog_ms == 100
    assert 0.05 / hw.control_period_s == pytest.approx(2)  # two bridge cycles per default simulator period


def test_the_model_list_is_the_control_tables():
    assert set(typing.get_args(DynamixelModel)) == set(ct.MODELS)


@pytest.mark.parametrize(("override", "field"), [
    ("hardware.right_id=1", "right_id"),
    ("hardware.watchdog_ms=90", "watchdog_ms"),
    ("hardware.watchdog_ms=40", "two control periods"),
    ("hardware.baud_rate=250000", "baud_rate"),
    ("hardware.model=AX-12A", "model"),
    ("hardware.left_id=253", "left_id"),
    ("hardware.max_wheel_speed_rad_s=30", "max_wheel_speed_rad_s"),
])
def test_bad_hardware_fields_are_one_clear_error(override, field):
    with pytest.raises(ConfigError) as err:
        load_robot("minibot", [override])
    assert "minibot.yaml" in str(err.value) and field in str(err.value)


def test_defaults_are_valid():
    assert Hardware().control_rate_hz == 40 and Hardware().ids == (1, 2)

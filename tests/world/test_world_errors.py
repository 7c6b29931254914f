"""Bad world files give one clear error naming the file and the field; unknown names list the shipped worlds."""

from __future__ import annotations

import pytest

from simnav.errors import ConfigError, UnknownNameError
from simnav.world import load_world


def test_unknown_world_lists_the_available_ones():
    with pytest.raises(UnknownNameError) as err:
        load_world("atlantis")
    assert "atlantis" in str(err.value) and "office" in str(err.value) and "corridor" in str(err.value)


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("walls: [{points: [[0, 0]]}]\nroadmap: {nodes: [[1, 1]]}\nspawns: [{x_m: 1, y_m: 1}]\n", "walls.0.points"),
        ("roadmap: {nodes: [[1, 1]], edges: [[0, 3]]}\nspawns: [{x_m: 1, y_m: 1}]\n", "roadmap"),
        ("roadmap: {nodes: [[1, 1]]}\nspawns: [{x_m: 1, y_m: 1}]\nagents: {pedestrians: -2}\n", "agents.pedestrians"),
        ("generator: {type: office, rooms: 99}\n", "generator.rooms"),
        ("walls: []\n", "roadmap"),
    ],
)
def test_invalid_fields_are_named(tmp_path, text, field):
    path = tmp_path / "w.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_world(path)
    assert str(path) in str(err.value) and field in str(err.value)


def test_malformed_yaml(tmp_path):
    path = tmp_path / "w.yaml"
    path.write_text("walls: [\n")
    with pytest.raises(ConfigError, match="malformed YAML at line"):
        load_world(path)

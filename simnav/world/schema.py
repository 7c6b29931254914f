"""World description (YAML schema): explicit layouts and generated ones.

A world file either lists its geometry explicitly (walls, boxes, cylinders, tables, chairs, shelves, doors) or
names a generator (``generator: {type: office, ...}``) that produces that explicit layout. Every world has a
roadmap (nodes in free space and edges between them) from which targets are drawn, robot spawn poses, and an
``agents`` section. All coordinates are in the ``world`` frame (x, y on the floor, z up), metres; angles in YAML
are degrees (``*_deg``).
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, model_validator

from simnav.config import FrozenModel

Vec2 = tuple[float, float]
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]


class Wall(FrozenModel):
    """A wall along a polyline: consecutive points joined by straight segments."""

    points: list[Vec2] = Field(min_length=2)
    thickness_m: Positive = 0.1
    height_m: Positive = 2.5


class Box(FrozenModel):
    """An axis-aligned (then yawed) box standing on the floor unless ``z_m`` lifts its bottom."""

    center: Vec2
    size_m: tuple[Positive, Positive, Positive]
    yaw_deg: float = 0.0
    z_m: NonNegative = 0.0
    color: tuple[float, float, float] = (0.55, 0.5, 0.45)


class Cylinder(FrozenModel):
    """A vertical cylinder (column, bin, plant pot) standing on the floor."""

    center: Vec2
    radius_m: Positive
    height_m: Positive
    color: tuple[float, float, float] = (0.5, 0.5, 0.55)


class Table(FrozenModel):
    """A table: four legs inset from the edge of a top, so the top overhangs (invisible to a low 2D lidar)."""

    center: Vec2
    size_m: tuple[Positive, Positive] = (1.4, 0.7)
    height_m: Positive = 0.74
    yaw_deg: float = 0.0
    top_thickness_m: Positive = 0.03
    leg_inset_m: NonNegative = 0.12
    leg_radius_m: Positive = 0.025

    @model_validator(mode="after")
    def _legs_under_top(self) -> Table:
        if 2 * self.leg_inset_m >= min(self.size_m):
            raise ValueError(f"leg_inset_m={self.leg_inset_m} puts the legs outside a {self.size_m} top")
        return self


class Chair(FrozenModel):
    """An office chair: seat on legs plus a backrest; ``yaw_deg`` is the direction the sitter faces."""

    center: Vec2
    yaw_deg: float = 0.0
    seat_size_m: Positive = 0.45
    seat_height_m: Positive = 0.45
    back_height_m: Positive = 0.45


class Shelf(FrozenModel):
    """An open shelf: side panels, a back panel and ``levels`` boards (see-through between boards)."""

    center: Vec2
    size_m: tuple[Positive, Positive, Positive] = (0.9, 0.35, 1.8)
    yaw_deg: float = 0.0
    levels: Annotated[int, Field(ge=2, le=10)] = 5


class Door(FrozenModel):
    """A hinged door leaf that opens and closes.

    The leaf turns about ``hinge`` from ``closed_yaw_deg`` (pointing across the doorway) by ``swing_deg``.
    It stays open ``open_s`` seconds, closed ``closed_s`` seconds (phase offset ``phase_s``), takes
    ``move_s`` to swing, and opens early when a person or robot waits within ``auto_open_radius_m``. A
    moving leaf pauses while it would come within ``safety_clearance_m`` of a person or robot (the presence
    sensor of a powered door).
    """

    hinge: Vec2
    width_m: Positive = 0.9
    closed_yaw_deg: float = 0.0
    swing_deg: float = 90.0
    thickness_m: Positive = 0.04
    height_m: Positive = 2.0
    open_s: Positive = 20.0
    closed_s: NonNegative = 6.0
    move_s: Positive = 1.5
    phase_s: NonNegative = 0.0
    auto_open_radius_m: NonNegative = 1.2
    safety_clearance_m: NonNegative = 0.05


class Roadmap(FrozenModel):
    """Navigation graph: nodes in free space (x, y) and undirected edges given as index pairs."""

    nodes: list[Vec2] = Field(min_length=1)
    edges: list[tuple[int, int]] = Field(default_factory=list)

    @model_validator(mode="after")
    def _edges_in_range(self) -> Roadmap:
        n = len(self.nodes)
        for k, (i, j) in enumerate(self.edges):
            if not (0 <= i < n and 0 <= j < n) or i == j:
                raise ValueError(f"edge {k} = ({i}, {j}) must join two different nodes in 0..{n - 1}")
        return self


class Spawn(FrozenModel):
    """A robot start pose in the world frame."""

    x_m: float
    y_m: float
    yaw_deg: float = 0.0

    @property
    def yaw_rad(self) -> float:
        return math.radians(self.yaw_deg)


class Agents(FrozenModel):
    """Moving things in the world: pedestrians (social force model) and other wandering robots."""

    pedestrians: Annotated[int, Field(ge=0, le=200)] = 10
    robots: Annotated[int, Field(ge=0, le=20)] = 0
    speed_mean_m_s: Positive = 1.34
    speed_std_m_s: NonNegative = 0.26
    robot_speed_m_s: Positive = 0.5
    single_file_wait_s: NonNegative = 0.0  # people wait this long at most before a single-file stretch a robot is in


class OfficeGenerator(FrozenModel):
    """Parameters of the office generator: rooms on both sides of a straight corridor."""

    type: Literal["office"] = "office"
    rooms: Annotated[int, Field(ge=2, le=20)] = 8
    room_width_m: Annotated[float, Field(ge=2.0, le=15.0)] = 4.5
    room_depth_m: Annotated[float, Field(ge=2.5, le=15.0)] = 5.0
    corridor_width_m: Annotated[float, Field(ge=1.2, le=6.0)] = 2.2
    door_width_m: Annotated[float, Field(ge=0.7, le=2.0)] = 1.0
    wall_height_m: Annotated[float, Field(ge=1.0, le=5.0)] = 2.6
    wall_thickness_m: Annotated[float, Field(ge=0.05, le=0.5)] = 0.12
    clutter_density: Annotated[float, Field(ge=0.0, le=1.0)] = 0.5
    door_leaves: bool = True
    seed: int = 0


class WorldSpec(FrozenModel):
    """A world: explicit geometry plus roadmap, spawns and agents (see module docstring)."""

    name: str = "unnamed"
    description: str = ""
    generator: OfficeGenerator | None = None
    walls: list[Wall] = Field(default_factory=list)
    boxes: list[Box] = Field(default_factory=list)
    cylinders: list[Cylinder] = Field(default_factory=list)
    tables: list[Table] = Field(default_factory=list)
    chairs: list[Chair] = Field(default_factory=list)
    shelves: list[Shelf] = Field(default_factory=list)
    doors: list[Door] = Field(default_factory=list)
    roadmap: Roadmap | None = None
    spawns: list[Spawn] = Field(default_factory=list)
    agents: Agents = Agents()

    @model_validator(mode="after")
    def _explicit_worlds_are_complete(self) -> WorldSpec:
        if self.generator is None:
            if self.roadmap is None:
                raise ValueError("an explicit world needs a 'roadmap' (nodes in free space and edges)")
            if not self.spawns:
                raise ValueError("an explicit world needs at least one entry in 'spawns'")
        return self

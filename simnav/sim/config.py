"""Simulator settings: clocks, agent counts, rendering backend."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from simnav.config import FrozenModel, check_whole_multiples


class SimConfig(FrozenModel):
    """How the world is stepped.

    The physics step is fixed; the control period and the agent update period must be whole multiples of it.
    ``pedestrians``/``wanderers`` of None take the world's ``agents`` section. With ``lockstep`` (the default, for
    closed loops) every reading is delivered exactly at its stamp plus latency; without it, camera frames rendered
    in the background are delivered when ready (never early, always in order) so that offline recording runs
    rendering in parallel with physics.
    """

    physics_dt_s: Annotated[float, Field(gt=0, le=0.02)] = 0.005
    control_dt_s: Annotated[float, Field(gt=0, le=1.0)] = 0.05
    agent_dt_s: Annotated[float, Field(gt=0, le=0.2)] = 0.04
    pedestrians: Annotated[int, Field(ge=0, le=200)] | None = None
    wanderers: Annotated[int, Field(ge=0, le=20)] | None = None
    depth_backend: Literal["auto", "gl", "raycast"] = "auto"
    spawn: Annotated[int, Field(ge=0)] | None = None
    lockstep: bool = True

    @model_validator(mode="after")
    def _multiples(self) -> SimConfig:
        check_whole_multiples(self, ("control_dt_s", "agent_dt_s"), "physics_dt_s")
        return self

    @property
    def substeps(self) -> int:
        return round(self.control_dt_s / self.physics_dt_s)

    @property
    def agent_substeps(self) -> int:
        return round(self.agent_dt_s / self.physics_dt_s)

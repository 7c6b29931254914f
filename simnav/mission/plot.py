"""Top view of a mission: the map, the roadmap, the path driven, the targets and the incidents."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simnav.agents.roadmap import RoadmapGraph
from simnav.world.footprint import obstacle_polygons
from simnav.world.schema import WorldSpec


def polygon_patch(poly):
    """A filled patch of a shapely polygon, holes included (a closed outer wall is a ring)."""
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    rings = [np.asarray(poly.exterior.coords)] + [np.asarray(r.coords) for r in poly.interiors]
    vertices = np.concatenate(rings)
    codes = np.concatenate([[MplPath.MOVETO] + [MplPath.LINETO] * (len(r) - 2) + [MplPath.CLOSEPOLY] for r in rings])
    return PathPatch(MplPath(vertices, codes), facecolor="0.55", edgecolor="none")


def plot_mission(world: WorldSpec, roadmap: RoadmapGraph, path_xy: np.ndarray, report, out_png: Path) -> Path:
    """Save a PNG of a mission.

    Args:
        world: the (expanded) world.
        roadmap: its roadmap.
        path_xy: (T, 2) positions of the base in the world over the mission, m.
        report: the :class:`simnav.mission.mission.MissionReport`.
        out_png: the file to write.

    Returns:
        ``out_png``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 8), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    # Map: static obstacles seen by any part of a robot up to 2 m, and the roadmap
    for poly in obstacle_polygons(world, 0.0, 2.0):
        ax.add_patch(polygon_patch(poly))
    for i, j in roadmap.edges:
        a, b = roadmap.nodes_xy[i], roadmap.nodes_xy[j]
        ax.plot([a[0], b[0]], [a[1], b[1]], color="0.85", lw=0.6, zorder=1)
    # Path, targets, incidents and interventions
    if len(path_xy):
        ax.plot(path_xy[:, 0], path_xy[:, 1], color="tab:blue", lw=1.0, zorder=3, label="path")
        ax.plot(*path_xy[0], "o", color="tab:blue", ms=6, zorder=4, label="start")
    for row in report.targets:
        ax.plot(row.x_m, row.y_m, "*", ms=11, zorder=5, color="tab:green" if row.reached else "tab:red",
                markeredgecolor="k", markeredgewidth=0.4)
        ax.annotate(str(row.index + 1), (row.x_m, row.y_m), xytext=(4, 4), textcoords="offset points", fontsize=7)
    markers = {"static": ("X", "tab:red"), "door": ("X", "tab:brown"), "people": ("o", "tab:orange"),
               "robots": ("s", "tab:purple")}
    for kind, (marker, colour) in markers.items():
        pts = np.array([[i["x_m"], i["y_m"]] for i in report.incidents if i["kind"] == kind]).reshape(-1, 2)
        if len(pts):
            ax.plot(pts[:, 0], pts[:, 1], marker, color=colour, ms=7, zorder=6, ls="none",
                    label=f"contact: {kind} ({len(pts)})")
    moved = np.array([[i["x_m"], i["y_m"]] for i in report.intervention_log]).reshape(-1, 2)
    if len(moved):
        ax.plot(moved[:, 0], moved[:, 1], "D", color="magenta", ms=7, zorder=6, ls="none",
                label=f"intervention ({len(moved)})")
    ax.set_aspect("equal")
    ax.set(xlabel="x (m)", ylabel="y (m)",
           title=f"{report.robot} in {report.world} ({report.nav.upper()}, pose: {report.pose_source}): "
                 f"{report.targets_reached}/{report.targets_requested} targets, {report.distance_m:.0f} m, "
                 f"{report.duration_s:.0f} s")
    ax.legend(loc="upper right", fontsize="small", framealpha=0.85)
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    return out_png

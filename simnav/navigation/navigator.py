"""The 3D-PTG reactive navigator (thesis §6.C): the robot as stacked prisms, one set of PTGs per prism.

One step (§6.C.5, Fig. 6.8), given the obstacle points in the base frame and the pose in a fixed frame:

1. sort the points into the robot's height bands and add the short-term memory's virtual obstacles;
2. for every path family (PTG), the TP-NavLimits of each band from that band's collision grid, combined by the
   minimum over bands (eq. 6.4);
3. the target (the furthest waypoint ahead that a PTG reports reachable, along a path that stays where a sensor
   sees: ``skip_within_view``) into each TP-space; the holonomic method
   (ND or VFF) picks a direction and a speed per PTG, and the target's own path is a second candidate when it is
   free up to the target (ND's filters drop gaps narrower than ceil(1% N) paths, such as a doorway that only one
   path passes); a path at the seam of TP-space (|alpha| > 135 degrees: turning around) gives way to its mirror image
   when that keeps the robot turning the way it already turns (ND sees the valley behind the robot as two, and the
   side it picks flips as the robot turns); the secure-distance ramp caps the speed at the one from which the
   robot stops short of the path's first obstacle; when ND finds no way on any PTG, it runs again with a lower
   floor for its gap search (``nd_fallback_floor_ratio``);
4. the best candidate by the weighted factors f1-f4 (eq. 6.5): collision-free distance, TP-angle to the target,
   closest approach of the path to the target, similarity to the previous command;
5. its (v, w), rescaled (keeping the path's curvature) for obstacles nearby (frontal ones weigh more) and for the
   approach to the final target, then limited in acceleration.

When no path of any family reaches the target (a wall close ahead, the target to the side or behind) and the target
lies more than ``turn_in_place_start_rad`` off the heading, the robot turns in place towards it if nothing is within
its turning circle: every PTG path moves forward while it turns, so close to a wall the secure distance stops them
all. When every path is blocked the robot backs away slowly for a few seconds if the space behind is free, then
stops and waits (§6.C.6); it backs only onto the path it drove along. Before that, a doorway the grids close (their
cells and margin keep 1.5-8.5 cm from the points: a 0.8 m doorway in front of the Giraff 5 cm off its centre line)
is squeezed through: the target's own path, checked exactly against the points up to a target 0.8 m ahead with a 2
cm margin, is followed slowly when that finds it free (``squeeze``, near waypoints flagged ``give_way``). A waypoint
to line up at (given a heading) whose spot is taken, an open door leaf or someone standing there, counts as reached
once the robot is close: it lines up where it is; if it then makes no progress for ``reapproach_after_s``, it aims at
that waypoint again once the spot is free. In front of a taken goal the robot stops, and backs away slowly
now and then to make room (someone in a doorway may be waiting to come out past it). Before a doorway someone stands
in (a waypoint flagged ``give_way``), the robot yields: it backs away along its trail to ``give_way_distance_m``
from the doorway, stops there and goes on once the doorway has been free for ``give_way_clear_s``. A target whose
distance has not improved for ``stuck_timeout_s`` marks the navigator stuck.
Units: m, s, rad; frames: ``base`` (x forward, y left), ``odom`` (any fixed frame the pose is given in).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from shapely.geometry import MultiPoint

from simnav.geometry import se2
from simnav.navigation.bands import Band, grow, sort_into_bands_flat
from simnav.navigation.binning import effective_obstacle_distance, merge_bands, points_near
from simnav.navigation.collision_grid import points_in_polygon
from simnav.navigation.holonomic import METHODS, HolonomicInput, NDConfig, index_to_alpha
from simnav.navigation.memory import MemoryConfig, ScanHistory, ShortTermMemory
from simnav.navigation.sensing import ViewSector

STATES = ("idle", "navigating", "turning", "squeezing", "reached", "blocked", "recovering", "waiting", "yielding")


@dataclass(frozen=True)
class NavigatorConfig:
    """Options of the 3D-PTG navigator; the defaults are the product (after MRPT's 3D sample and §6.C).

    Attributes:
        ptgs: path families (``"C"``, ``"alpha"``, ``"CS"``, ``"C-backward"``), one set of grids per band each.
        num_paths: paths per PTG.
        ref_distance_m: horizon of the TP-spaces, m.
        grid_resolution_m: cell size of the collision grids, m.
        footprint_margin_m: every section is grown by this much for the collision grids, so that chosen paths keep
            this clearance (the robot's true shape is used for the blocked-goal and recovery checks), m.
        holonomic: ``"nd"`` (default, as in §6.C.6) or ``"vff"``.
        nd_crowded_floor_ratio: ND's :attr:`~simnav.navigation.holonomic.NDConfig.crowded_floor_ratio` (None:
            MRPT's gap search).
        nd_fallback_floor_ratio: when ND finds no way on any PTG (every candidate would stand still), ND runs
            again on each with this ``crowded_floor_ratio`` before the robot backs away or waits (None: MRPT's ND
            alone). Beside an open door leaf, the paths turning away from it free for 0.2-0.67 of the horizon and
            MRPT's floor at 0.6, the gap of the freest two was too narrow for ND's filters, and the robot waited
            27 s; office batches (seeds 1-48): 19 interventions with it against 29 (1 of them boxed in against 9).
        secure_distance_m: the secure-distance ramp: a candidate path's speed is the one from which the robot stops
            (``reaction_time_s`` at that speed, then braking at ``braking_m_s2``) this short of the first obstacle
            along the path; a path free for less than this gets speed 0, m. The ramp is in metres, not in
            normalised distance, so that it means the same in a 1 m hallway as in an open hall.
        braking_m_s2: deceleration the ramp assumes (below the robot's acceleration limit), m/s^2.
        reaction_time_s: time at the old speed before braking starts (a navigation period plus the command's
            latency), s.
        weight_free_distance: w1 of eq. 6.5 (collision-free distance of the candidate).
        weight_target_angle: w2 (TP-angle between the candidate and the target).
        weight_target_nearness: w3 (closest approach of the candidate's path to the target).
        weight_hysteresis: w4 (similarity of the command to the previous one).
        weight_target_distance: reward for reaching the target along the candidate within its free distance.
        backward_priority: score factor of backward PTGs (they are a last resort).
        target_allowed_distance_m: the final target counts as reached within this distance, m.
        waypoint_allowed_distance_m: intermediate waypoints count as passed within this distance, m.
        through_doorway_first: until the robot has crossed the doorway waypoint it passed last (flagged ``give_way``,
            without a heading; crossed: past the line through it square to the route's leg), it aims at no waypoint
            beyond the one after it (the exit waypoint straight on). A doorway counts as passed within its allowed
            distance, often before the robot is through: without this, a robot 0.16 m short of a doorway's wall line
            aimed at a corridor waypoint beyond, turned in place towards it, and drove into the room along the wall
            (the office's long runs). Off by default: over the office's long runs it did not lower the interventions
            (see the README).
        waypoint_heading_tolerance_rad: a waypoint given a heading counts as passed only once the robot faces that
            heading within this; until then it turns in place there (when its turning circle is free), rad.
        taken_waypoint_pass_m: a waypoint given a heading whose spot is taken (the robot standing on it at that
            heading would overlap a sensed or remembered point: an open door leaf, someone standing there) counts
            as reached within this distance: the robot lines up where it is, m.
        taken_waypoint_wait_s: ... after the robot has stopped and waited this long for the spot to free up
            (someone walking past it frees it in a second or two, an open door leaf does not); once per waypoint
            (a leaf's edge found on the spot in some steps and not in others does not restart the wait), s.
        reapproach_after_s: with no progress for this long, while not yielding, the robot aims again at the last
            waypoint it passed if that one has a heading and the robot has not crossed the waypoint after it, once its
            spot is free, with its given allowed distance; once per waypoint; the one before follows by the same rule
            (:meth:`ReactiveNavigator3D._reapproach`). A doorway's approach waypoint lined up at off its spot
            (someone stood there) left the robot where it found no path through a 0.8 m doorway, turning on the spot
            until the stuck timeout (the flat). None: never, s.
        target_slow_down_m: the speed falls linearly over this distance to the final target, m.
        target_min_speed: relative speed kept at the final target (0..1).
        slow_down_distance_m: obstacles whose effective distance (gap to the robot's section, divided by the
            direction weight) is below this reduce the speed, m.
        stop_distance_m: at this effective distance the speed reaches ``min_speed_near_obstacles``, m.
        min_speed_near_obstacles: relative speed floor of the obstacle speed regulation (0..1): near obstacles the
            fastest point of the robot (forward speed plus yaw rate times the circumradius) moves at most this
            fraction of the top speed.
        lateral_obstacle_weight: how much an obstacle straight to the side counts relative to one in front.
        limit_to_view: when the navigator is given the sensors' fields of view (``view``), a path counts as free
            only as far as it stays where they see from the robot's current pose (or inside the robot's own
            outline): what no sensor sees, behind a 240-degree lidar, is not known to be free. Off by default, as
            in §6.C and MRPT: paths that turn the robot around into the space behind it then look free all the
            way, and among people blocking the way ahead the robot turns back and forth between them and the
            people it then sees; with it on, it waits instead (in the simulated crowds that made no fewer
            interventions: see the README).
        skip_within_view: a waypoint after the current one counts as reachable (to cut to it) only along a path
            that stays where a sensor sees from the robot's pose (as ``limit_to_view``, for this choice alone; needs
            ``view``). A robot facing away from a room's wall took the unseen space behind it for free, cut from
            the room's waypoints to a corridor waypoint beyond the wall and turned on the spot inside the room (the
            office's long runs).
        memory: use the short-term memory.
        memory_config: its options.
        recovery_speed_m_s: backward speed while recovering, m/s.
        recovery_min_s: once backing away, keep at it at least this long before moving forward again, s.
        recovery_duration_s: back away at most this long, then stop and wait, s.
        recovery_retry_s: after waiting this long, back away again (someone who waits to pass the robot, in a
            doorway, may need more room than one backing gives); in front of a taken goal, after waiting this
            long, back away while the space behind is free (no trail needed), s.
        recovery_clearance_m: back away only if the space behind is free for this distance, m.
        recovery_trail_s: backing away only goes where the robot itself drove, facing the same way (within 0.1 m
            and 20 degrees; yielding: every vertex of its sections within ``footprint_margin_m`` of where it was),
            within this many seconds: the sensors see little behind the robot, the path it came along was free, s.
        turn_in_place: turn in place towards a target that no path reaches (see the module doc).
        turn_in_place_start_rad: ... when the target lies further than this off the heading, rad.
        turn_in_place_stop_rad: ... until it lies within this, or a path reaches it, rad.
        turn_in_place_stalled_rad: when no path moves at all, the robot turns in place towards a target lying
            further than this off the heading (by default ``turn_in_place_stop_rad``; 3 degrees squares up a robot
            standing 10 degrees askew in a 0.8 m doorway, its target 7 degrees off, which found no path through it
            and waited there for good, but did not lower the flat's interventions: see the README), rad.
        turn_in_place_retry_s: after turning in place, the robot turns in place again only once it has moved
            ``turn_in_place_retry_m`` or after this long: when the paths the holonomic method picks turn away from
            the target, they keep the lead for a while instead of the two taking turns for ever (unless no path
            moves at all: then turning beats waiting), s.
        turn_in_place_retry_m: ... or once it has moved this far, m.
        squeeze: drive through a doorway the collision grids close (see the module doc): when no path moves, the
            robot does not turn in place, a doorway (a waypoint flagged ``give_way`` among the few before and
            after the current one) lies within ``squeeze_reach_m`` and the target within 30 degrees of the heading
            and within ``squeeze_reach_m`` along a PTG's path, that path is followed at most at
            ``squeeze_speed_m_s`` (not again within ``recovery_clearance_m`` of where a squeeze ended with every
            path blocked) if the grids block it more than ``secure_distance_m`` short of the target and the
            robot's true sections grown by ``squeeze_margin_m`` sweep it up to the target without containing any
            sensed or remembered point. A grid marks a point where the section grown by ``footprint_margin_m``
            covers its cell's centre, so with 5 cm cells and margin it keeps 1.5 to 8.5 cm from the points, and
            0.8 m doorways, 0.28 m wider than the Giraff, closed in front of a robot 5 cm off their centre line,
            nothing else near. Only at doorways: in the office's corridors it let the robot creep past people 2-5 cm
            from its outline.
        squeeze_margin_m: ... the margin of that exact test, m.
        squeeze_reach_m: ... how far the doorway and, along the path, the target may lie, m.
        squeeze_speed_m_s: ... the top speed while squeezing through, m/s.
        stuck_timeout_s: the navigator reports ``stuck`` when the distance to the furthest waypoint it has aimed at
            (a skipped waypoint aimed at again does not count) has not improved by ``stuck_progress_m`` for this
            long (passing a waypoint is progress), s.
        stuck_progress_m: progress that resets the stuck timer, m.
        blocked_check_m: within this distance of the goal, check whether the robot would collide if it stood on
            the goal (then it stops there, state ``blocked``, until the goal clears, backing away now and then to
            make room: ``recovery_retry_s``), m.
        blocked_confirm_steps: consecutive steps the goal must look blocked before stopping.
        give_way: yield at doorways (the waypoints flagged ``give_way`` in :meth:`ReactiveNavigator3D.set_waypoints`):
            when the robot is within ``give_way_check_m`` of the next such waypoint (with ``give_way_until_crossed``,
            also of one it passed but has not crossed) and, standing on it facing along the route, would overlap a
            sensed or remembered point for ``blocked_confirm_steps`` steps (someone stands in the doorway, often waiting
            to come out past the robot), it backs away straight at ``give_way_speed_m_s`` while the space behind is free
            (and, with ``give_way_on_trail``, on its own trail), until ``give_way_distance_m`` from the doorway, and
            waits (state ``yielding``) until the doorway has been free for ``give_way_clear_s``. Without it the robot
            turned back and forth on the spot in front of the doorway, the way in blocked and the corridor behind free,
            while the people inside waited for it to make room.
        give_way_check_m: look at the doorway from this close, m.
        give_way_distance_m: back away until this far from the doorway, m. At 1.5 m the Giraff's front stays
            0.5-0.6 m clear of the doorway for the people in it to step out sideways; at 1.1 m it stood on the
            corridor node they were heading for, and both waited (the office's doorway deadlocks, see the README).
        give_way_speed_m_s: backward speed while yielding, m/s.
        give_way_clear_s: the doorway must look free this long before the robot goes on, s.
        give_way_on_trail: yielding backs only onto the robot's own trail, as recovery does (``recovery_trail_s``),
            its footprint where it was: the space behind a robot with a forward-looking lidar is mostly unseen, and
            backing wherever no point was sensed ran it into the walls behind it (in the flat's 1 m hallway, 12 of
            17 contacts).
        give_way_seen_free_s: with ``give_way_on_trail``, yielding also backs off its trail where a level 2D lidar
            saw the space free within the last this many seconds, ``_SEEN_FREE_CLEARANCE_M`` (0.3 m) around every
            point of the outline moved back that lies outside the outline now (:class:`simnav.navigation.memory.
            ScanHistory`: the newest scan in each bearing decides; rays from the apex of the widest of the
            navigator's view sectors, the lidar's): into open space, not into a doorway or the flat's 1 m hallway.
            None: only onto the trail. The robot turns in place at a doorway's approach waypoint to face it, so its
            trail with that heading ends there, and the corridor behind it, seen as it came, was left unused while
            the people in the doorway waited for room to come out (the office's long-run share: 14 interventions
            with it against 20 and one more without, see the README).
        give_way_turn_back: off its trail when yielding (it turned in place to face the doorway at the doorway's
            approach waypoint), first turn in place back to a heading it came there with, the doorway kept within
            60 degrees of the heading, then back along the trail; without it the robot stands where it turned.
            Off by default: over the office's batches it did not lower the interventions (see the README).
        give_way_until_crossed: also yield at a doorway waypoint the robot passed within its allowed distance but
            has not crossed yet (it lies behind the line through the waypoint square to the route's leg), not only
            at the current and next waypoints. Off by default, as ``give_way_turn_back``.
        spin_limit_rad: once the robot has turned this much on the spot (within ``_SPIN_RESET_M``; None: no
            limit), rad, it takes no path that turns it around (beyond the TP-space seam): it turns to face the
            target the short way, when its turning circle is free, and waits there for a path that does not turn it
            around. Without it, the way to the target blocked by people, ND picked the valley behind the robot,
            which stayed behind it as it turned: the robot spun on the spot, back and forth, for minutes.
    """

    ptgs: tuple[str, ...] = ("C", "alpha", "CS")
    num_paths: int = 121
    ref_distance_m: float = 4.0
    grid_resolution_m: float = 0.05
    footprint_margin_m: float = 0.05
    holonomic: str = "nd"
    nd_crowded_floor_ratio: float | None = None
    nd_fallback_floor_ratio: float | None = 0.5
    secure_distance_m: float = 0.10
    braking_m_s2: float = 0.4
    reaction_time_s: float = 0.2
    weight_free_distance: float = 0.5
    weight_target_angle: float = 0.2
    weight_target_nearness: float = 8.0
    weight_hysteresis: float = 0.1
    weight_target_distance: float = 0.3
    backward_priority: float = 0.5
    target_allowed_distance_m: float = 0.3
    waypoint_allowed_distance_m: float = 1.0
    through_doorway_first: bool = False
    waypoint_heading_tolerance_rad: float = math.radians(20.0)
    taken_waypoint_pass_m: float = 0.6
    taken_waypoint_wait_s: float = 0.0
    reapproach_after_s: float | None = 8.0
    target_slow_down_m: float = 0.8
    target_min_speed: float = 0.15
    slow_down_distance_m: float = 0.6
    stop_distance_m: float = 0.05
    min_speed_near_obstacles: float = 0.4
    lateral_obstacle_weight: float = 0.3
    limit_to_view: bool = False
    skip_within_view: bool = True
    memory: bool = True
    memory_config: MemoryConfig = field(default_factory=MemoryConfig)
    recovery_speed_m_s: float = 0.08
    recovery_min_s: float = 1.0
    recovery_duration_s: float = 3.0
    recovery_retry_s: float = 8.0
    recovery_clearance_m: float = 0.3
    recovery_trail_s: float = 20.0
    turn_in_place: bool = True
    turn_in_place_start_rad: float = math.radians(60.0)
    turn_in_place_stop_rad: float = math.radians(15.0)
    turn_in_place_stalled_rad: float = math.radians(15.0)
    turn_in_place_retry_s: float = 10.0
    turn_in_place_retry_m: float = 0.3
    squeeze: bool = True
    squeeze_margin_m: float = 0.02
    squeeze_reach_m: float = 0.8
    squeeze_speed_m_s: float = 0.1
    stuck_timeout_s: float = 30.0
    stuck_progress_m: float = 0.2
    blocked_check_m: float = 2.0
    blocked_confirm_steps: int = 3
    give_way: bool = True
    give_way_check_m: float = 1.9
    give_way_distance_m: float = 1.5
    give_way_speed_m_s: float = 0.12
    give_way_clear_s: float = 1.0
    give_way_on_trail: bool = True
    give_way_seen_free_s: float | None = 20.0
    give_way_turn_back: bool = False
    give_way_until_crossed: bool = False
    spin_limit_rad: float | None = None

    def __post_init__(self) -> None:
        checks = [
            (len(self.ptgs) >= 1, "ptgs must name at least one path family"),
            (self.num_paths >= 3, "num_paths must be >= 3"),
            (self.ref_distance_m > 0, "ref_distance_m must be > 0"),
            (0 < self.grid_resolution_m < self.ref_distance_m, "grid_resolution_m must be in (0, ref_distance_m)"),
            (self.footprint_margin_m >= self.grid_resolution_m / math.sqrt(2) - 1e-9,
             "footprint_margin_m must be at least half the diagonal of a grid cell (grid_resolution_m / sqrt(2))"),
            (0 <= self.secure_distance_m < self.ref_distance_m, "secure_distance_m must be in [0, ref_distance_m)"),
            (self.braking_m_s2 > 0, "braking_m_s2 must be > 0"),
            (self.reaction_time_s >= 0, "reaction_time_s must be >= 0"),
            (self.target_allowed_distance_m > 0, "target_allowed_distance_m must be > 0"),
            (0 < self.waypoint_heading_tolerance_rad <= math.pi, "waypoint_heading_tolerance_rad must be in (0, pi]"),
            (self.taken_waypoint_pass_m >= 0, "taken_waypoint_pass_m must be >= 0"),
            (self.taken_waypoint_wait_s >= 0, "taken_waypoint_wait_s must be >= 0"),
            (self.reapproach_after_s is None or self.reapproach_after_s > 0, "reapproach_after_s must be > 0 or None"),
            (0 <= self.min_speed_near_obstacles <= 1, "min_speed_near_obstacles must be in [0, 1]"),
            (0 < self.lateral_obstacle_weight <= 1, "lateral_obstacle_weight must be in (0, 1]"),
            (self.stop_distance_m < self.slow_down_distance_m, "stop_distance_m must be < slow_down_distance_m"),
            (self.stuck_timeout_s > 0, "stuck_timeout_s must be > 0"),
            (self.squeeze_margin_m >= 0 and self.squeeze_reach_m > 0 and self.squeeze_speed_m_s > 0,
             "need squeeze_margin_m >= 0, squeeze_reach_m > 0 and squeeze_speed_m_s > 0"),
            *[(getattr(self, name) >= 0, f"{name} must be >= 0, got {getattr(self, name)}")
              for name in ("give_way_check_m", "give_way_distance_m", "give_way_speed_m_s", "give_way_clear_s")],
            (self.give_way_seen_free_s is None or self.give_way_seen_free_s > 0,
             f"give_way_seen_free_s must be None or > 0 s, got {self.give_way_seen_free_s}"),
            (self.spin_limit_rad is None or self.spin_limit_rad > 0,
             f"spin_limit_rad must be None or > 0 rad, got {self.spin_limit_rad}"),
            (0 <= self.turn_in_place_stop_rad < self.turn_in_place_start_rad <= math.pi,
             "need 0 <= turn_in_place_stop_rad < turn_in_place_start_rad <= pi"),
            (0 <= self.turn_in_place_stalled_rad <= self.turn_in_place_stop_rad,
             "need 0 <= turn_in_place_stalled_rad <= turn_in_place_stop_rad"),
            (self.turn_in_place_retry_s >= 0 and self.turn_in_place_retry_m >= 0,
             "turn_in_place_retry_s and turn_in_place_retry_m must be >= 0"),
            (isinstance(self.holonomic, str) and self.holonomic.lower() in METHODS,
             f"holonomic must be one of {', '.join(METHODS)}, got {self.holonomic!r}"),
            *[(getattr(self, name) is None or 0 < getattr(self, name) <= 1,
               f"{name} must be None or in (0, 1], got {getattr(self, name)}")
              for name in ("nd_crowded_floor_ratio", "nd_fallback_floor_ratio")],
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"NavigatorConfig: {message}")


@dataclass(frozen=True)
class NavCommand:
    """The output of one navigator step.

    Attributes:
        v_m_s: forward speed command, m/s.
        w_rad_s: yaw rate command, rad/s.
        state: one of ``STATES`` (``turning``: turning in place towards the target; ``squeezing``: through a
            doorway the grids close, ``NavigatorConfig.squeeze``).
        stuck: True when the target has not come closer for ``stuck_timeout_s``.
        target_index: index of the waypoint being aimed at, -1 when idle.
        ptg: name of the chosen path family ('' when none).
        path_index: chosen path k of that PTG (-1 when none).
        free_distance: normalised collision-free distance of the chosen path.
        speed: relative speed (0..1) after all regulation.
        runtime_s: wall time of the step, s.
    """

    v_m_s: float
    w_rad_s: float
    state: str
    stuck: bool = False
    target_index: int = -1
    ptg: str = ""
    path_index: int = -1
    free_distance: float = 0.0
    speed: float = 0.0
    runtime_s: float = 0.0


@dataclass
class _Candidate:
    ptg: int
    k: int
    speed: float
    free: float
    score: float


class ReactiveNavigator3D:
    """The reactive navigator for one robot.

    Args:
        bands: the robot's height bands (``robot_bands(spec)``; ``planar_bands(spec)`` for the 2D navigator).
        max_v_m_s: the robot's top speed, m/s.
        max_w_rad_s: the robot's top yaw rate, rad/s.
        max_acc_m_s2: linear acceleration limit of the output, m/s^2 (None = unlimited).
        max_ang_acc_rad_s2: angular acceleration limit of the output, rad/s^2 (None = unlimited).
        config: navigator options.
        cache_dir: where collision grids are cached (None = the default cache).
        view: the horizontal fields of view of the range sensors, base frame (:func:`simnav.navigation.sensing.
            view_sectors` of the robot); with ``config.limit_to_view``, paths are free only as far as they stay
            in view (None: everything counts as seen, as in §6.C).
        free_space_x_m: (B, 2) per band, the forward distances (base x, m) where the depth camera sees the band's
            whole height (:func:`simnav.navigation.sensing.camera_free_space` of the robot): with
            ``memory_config.whole_band_view`` the short-term memory counts its cone as seen free only there.
    """

    def __init__(self, bands: Sequence[Band], max_v_m_s: float, max_w_rad_s: float, *,
                 max_acc_m_s2: float | None = None, max_ang_acc_rad_s2: float | None = None,
                 config: NavigatorConfig | None = None, cache_dir: str | None = None,
                 view: Sequence[ViewSector] | None = None, free_space_x_m: np.ndarray | None = None) -> None:
        from simnav.navigation.holonomic import make_holonomic
        from simnav.navigation.ptgspace import PTGSpace

        self.config = cfg = config or NavigatorConfig()
        self.bands = list(bands)
        self.max_v_m_s, self.max_w_rad_s = float(max_v_m_s), float(max_w_rad_s)
        self._acc = (max_acc_m_s2, max_ang_acc_rad_s2)
        padded = [grow(band, cfg.footprint_margin_m) for band in self.bands]
        self._spaces = [PTGSpace(name, padded, max_v_m_s, max_w_rad_s, cfg.num_paths, cfg.ref_distance_m,
                                 cfg.grid_resolution_m, cache_dir) for name in cfg.ptgs]
        if not all(space.shares_grid_geometry(self._spaces[0]) for space in self._spaces):
            raise ValueError("NavigatorConfig: every PTG must share the grid geometry (same bands, resolution, ref)")
        options = {"crowded_floor_ratio": cfg.nd_crowded_floor_ratio} if cfg.holonomic.lower() == "nd" else {}
        self._holonomic = [make_holonomic(cfg.holonomic, **options) for _ in self._spaces]  # own hysteresis each
        fallback = cfg.holonomic.lower() == "nd" and cfg.nd_fallback_floor_ratio is not None
        self._fallback = [make_holonomic("nd", crowded_floor_ratio=cfg.nd_fallback_floor_ratio)
                          for _ in self._spaces] if fallback else None
        self.free_space_x_m = None if free_space_x_m is None else np.array(free_space_x_m, dtype=np.float64)
        if cfg.memory and cfg.memory_config.whole_band_view and self.free_space_x_m is None:
            raise ValueError("NavigatorConfig: memory_config.whole_band_view needs the navigator's free_space_x_m "
                             "(camera_free_space(robot, bands))")
        band_view = self.free_space_x_m if cfg.memory_config.whole_band_view else None
        self._memory = (ShortTermMemory(len(self.bands), cfg.memory_config, band_view, view)
                        if cfg.memory else None)
        self._band_boxes = [(band.polygon.min(axis=0), band.polygon.max(axis=0)) for band in self.bands]
        self._outline_xy = np.unique(np.concatenate([band.polygon for band in self.bands]), axis=0)  # (V, 2) base
        circumradii_m = np.array([float(np.max(np.hypot(b.polygon[:, 0], b.polygon[:, 1]))) for b in self.bands])
        self._turn_radii_m = circumradii_m + cfg.footprint_margin_m
        self._tight_turn_radii_m = circumradii_m + min(cfg.footprint_margin_m, _TIGHT_TURN_MARGIN_M)
        self._squeeze_polygons = [grow(band, min(cfg.squeeze_margin_m, cfg.footprint_margin_m)).polygon
                                  for band in self.bands]
        self._squeeze_radii_m = circumradii_m + min(cfg.squeeze_margin_m, cfg.footprint_margin_m)
        self._robot_radius_m = max(float(np.max(np.hypot(b.polygon[:, 0], b.polygon[:, 1]))) for b in self.bands)
        self.view = None if view is None else tuple(view)
        self._scans = (ScanHistory(_scan_origin_xy(self.view), cfg.give_way_seen_free_s,
                                   clearance_m=_SEEN_FREE_CLEARANCE_M)
                       if cfg.give_way and cfg.give_way_on_trail and cfg.give_way_seen_free_s is not None else None)
        hull = MultiPoint(self._outline_xy.tolist()).convex_hull.exterior
        self._hull_xy = np.asarray(hull.coords)[:-1]  # (H, 2) the robot's outline, base frame
        self._hull_samples_xy = np.array([hull.interpolate(s).coords[0]  # every 4 cm along it
                                          for s in np.linspace(0.0, hull.length, int(hull.length / 0.04) + 1)])
        seen = ([_view_limits(space, self.view, self.bands) for space in self._spaces]
                if self.view is not None and (cfg.limit_to_view or cfg.skip_within_view) else None)
        self._view_limits = seen if cfg.limit_to_view else None
        self._skip_view_limits = seen if cfg.skip_within_view else None
        self.reset()

    # ---------------------------------------------------------------------------------------------- targets
    def reset(self) -> None:
        """Forget targets, memory and the previous command."""
        self._waypoints = np.zeros((0, 2))
        self._allow_skip, self._allowed_m = np.zeros(0, dtype=bool), np.zeros(0)
        self._headings = np.zeros(0)
        self._give_way = np.zeros(0, dtype=bool)
        self._held_steps, self._yielding = 0, False  # steps the next doorway looked taken; yielding before it
        self._doorway_clear_since_s: float | None = None
        self._target = 0
        self._first_unpassed = 0  # the first waypoint not driven past (later ones up to _target were skipped)
        self._aligning = False  # the current waypoint is reached but not yet faced at its heading
        self._last_cmd = (0.0, 0.0)
        self._last_stamp_s: float | None = None
        self._best_distance = math.inf
        self._best_distance_stamp_s: float | None = None
        self._stuck_since_kept_s: float | None = None  # set_waypoints(keep_stuck_timer=True): no progress since
        self._blocked_since_s: float | None = None
        self._progress_target = -1
        self._goal_blocked_steps = 0
        self._goal_blocked_since_s: float | None = None
        self._spot_taken_steps = 0
        self._spot_taken_since: tuple[int, float] = (-1, math.nan)  # (waypoint, stamp) its spot was found taken
        self._turning = False
        self._spin: tuple[float, float, float, float] | None = None  # (x, y) spun at, last yaw, rad turned since
        self._turn_end: tuple[float, float, float] | None = None  # (stamp, x, y) where the last turn in place ended
        self._seam_side = 0  # the way the robot turns on paths across alpha = +-pi: +1 left, -1 right, 0 none
        self._trail: deque[tuple[float, float, float, float]] = deque()  # (stamp, x, y, yaw) of recent poses
        for method in [*getattr(self, "_holonomic", []), *(getattr(self, "_fallback", None) or [])]:
            method.reset()
        if self._memory is not None:
            self._memory.reset()
        if self._scans is not None:
            self._scans.reset()

    def set_waypoints(self, waypoints_xy: np.ndarray, allow_skip: np.ndarray | None = None,
                      allowed_distance_m: np.ndarray | None = None, headings_rad: np.ndarray | None = None,
                      give_way: np.ndarray | None = None, keep_stuck_timer: bool = False) -> None:
        """Follow waypoints in order without stopping; the last one is the goal.

        Args:
            waypoints_xy: (W, 2) waypoints in the fixed frame of the poses, m.
            allow_skip: (W,) whether the navigator may cut past each waypoint once a later one is reachable
                (default all True); a waypoint in a doorway is best passed through, not skipped.
            allowed_distance_m: (W,) distance within which each intermediate waypoint counts as passed, m
                (default ``waypoint_allowed_distance_m``; the goal always uses ``target_allowed_distance_m``).
            headings_rad: (W,) heading at which to pass each waypoint, in the fixed frame, rad; NaN where any will
                do (the default). Such a waypoint is passed once the robot is within its allowed distance and faces
                the heading within ``waypoint_heading_tolerance_rad``: it turns in place there (e.g. to line up
                with a doorway before driving through it).
            give_way: (W,) waypoints to yield at while someone stands on them (doorways; default none; see
                ``NavigatorConfig.give_way``).
            keep_stuck_timer: the same goal on a new route (re-planned): the time without progress runs on from
                the old route until the robot makes progress on the new one (else a robot re-planned every few
                seconds would never count as stuck).
        """
        kept_since_s = self._best_distance_stamp_s if keep_stuck_timer and len(self._waypoints) else None
        wp = np.asarray(waypoints_xy, dtype=np.float64).reshape(-1, 2)
        if len(wp) == 0 or not np.isfinite(wp).all():
            raise ValueError(f"waypoints must be a non-empty (W, 2) finite array, got shape {wp.shape}")
        skip = np.ones(len(wp), dtype=bool) if allow_skip is None else np.asarray(allow_skip, dtype=bool)
        near = (np.full(len(wp), self.config.waypoint_allowed_distance_m) if allowed_distance_m is None
                else np.array(allowed_distance_m, dtype=np.float64))
        heading = (np.full(len(wp), np.nan) if headings_rad is None
                   else np.asarray(headings_rad, dtype=np.float64).copy())
        yields = np.zeros(len(wp), dtype=bool) if give_way is None else np.asarray(give_way, dtype=bool)
        if skip.shape != (len(wp),) or near.shape != (len(wp),) or heading.shape != (len(wp),) or \
                yields.shape != (len(wp),):
            raise ValueError(f"allow_skip, allowed_distance_m, headings_rad and give_way must have shape "
                             f"({len(wp)},)")
        near[-1] = self.config.target_allowed_distance_m
        self._waypoints, self._allow_skip, self._allowed_m, self._target = wp, skip, near, 0
        self._given_allowed_m, self._reapproached = near.copy(), set()
        self._first_unpassed, self._progress_target = 0, -1  # waypoints before the first are passed
        self._headings, self._aligning, self._give_way = heading, False, yields
        self._held_steps, self._yielding, self._doorway_clear_since_s = 0, False, None
        self._best_distance, self._best_distance_stamp_s = math.inf, None
        self._stuck_since_kept_s = kept_since_s
        self._blocked_since_s = self._goal_blocked_since_s = None
        self._spot_taken_steps, self._spot_taken_since = 0, (-1, math.nan)
        self._turning, self._turn_end = False, None
        self._squeezing, self._squeeze_stuck_xy = False, None
        self._seam_side = 0

    def set_target(self, target_xy: Sequence[float]) -> None:
        """Go to one target (fixed frame, m)."""
        self.set_waypoints(np.asarray(target_xy, dtype=np.float64).reshape(1, 2))

    @property
    def goal_reached(self) -> bool:
        return len(self._waypoints) > 0 and self._target >= len(self._waypoints)

    # ------------------------------------------------------------------------------------------------ step
    def step(self, stamp_s: float, T_odom_base: np.ndarray, points_base: np.ndarray,
             scan_points_base: np.ndarray | None = None) -> NavCommand:
        """One navigation step.

        Args:
            stamp_s: time, s.
            T_odom_base: (3, 3) SE(2) pose of the base in the frame of the waypoints.
            points_base: (P, 3) obstacle points in the base frame, m (every range sensor; floor points allowed).
            scan_points_base: (S, 3) further obstacle points that are a level 2D lidar's (not also in
                ``points_base``), m: the short-term memory also takes the space before them as seen free
                (:meth:`simnav.navigation.sensing.SensedObstacles.split_points_base` gives both).

        Returns:
            The velocity command and what the navigator decided.
        """
        t0 = time.perf_counter()
        dt = 0.0 if self._last_stamp_s is None else max(stamp_s - self._last_stamp_s, 0.0)
        self._last_stamp_s = stamp_s
        if len(self._waypoints) == 0 or self.goal_reached:
            return self._output(0.0, 0.0, dt, t0, "reached" if self.goal_reached else "idle")
        self._remember_pose(stamp_s, T_odom_base)
        if self.config.spin_limit_rad is not None:
            self._update_spin(T_odom_base)
        self._advance_waypoints(T_odom_base)
        if self.goal_reached:
            return self._output(0.0, 0.0, dt, t0, "reached")
        # Obstacles per band (sensed + remembered), as one array: band b owns xy[ptr[b]:ptr[b + 1]]
        cfg = self.config
        n_bands = len(self.bands)
        xy, ptr = sort_into_bands_flat(points_base, self.bands, max_xy_m=1.1 * cfg.ref_distance_m)
        scan_xy = scan_ptr = None
        if scan_points_base is not None and len(scan_points_base):
            scan_xy, scan_ptr = sort_into_bands_flat(scan_points_base, self.bands, max_xy_m=1.1 * cfg.ref_distance_m)
            if self._scans is not None:
                self._scans.add(stamp_s, T_odom_base, scan_xy)
        if self._memory is not None:
            virtual_xy, virtual_ptr = self._memory.update_flat(stamp_s, T_odom_base, xy, ptr, scan_xy, scan_ptr)
        if scan_xy is not None:
            xy, ptr = merge_bands(xy, ptr, scan_xy, scan_ptr)
        if self._memory is not None:
            if len(virtual_xy):
                xy, ptr = merge_bands(xy, ptr, virtual_xy, virtual_ptr)
        band_xy = [xy[ptr[b]:ptr[b + 1]] for b in range(n_bands)]
        # A waypoint to line up at whose spot is taken, close by: wait for it, then reached where the robot is
        if not self._aligning and self._lineup_spot_taken(T_odom_base, band_xy):
            if self._spot_taken_since[0] != self._target:
                self._spot_taken_since = (self._target, stamp_s)
            if stamp_s - self._spot_taken_since[1] < cfg.taken_waypoint_wait_s:
                return self._output(0.0, 0.0, dt, t0, "waiting", self._target)
            self._allowed_m[self._target] = float(np.linalg.norm(self._waypoints[self._target] - T_odom_base[:2, 2]))
            self._advance_waypoints(T_odom_base)
            if self.goal_reached:
                return self._output(0.0, 0.0, dt, t0, "reached")
        # A waypoint reached but not faced at its heading: turn in place to it (pass it if there is no room)
        if self._aligning:
            w = self._alignment_turn(T_odom_base, xy, ptr)
            if w != 0.0:
                w *= self._point_speed_scale(0.0, w, self._obstacle_speed_factor(band_xy))
                return self._output(0.0, w, dt, t0, "turning", self._target)
            self._pass_waypoint()
            self._advance_waypoints(T_odom_base)
            if self.goal_reached:
                return self._output(0.0, 0.0, dt, t0, "reached")
        # TP-NavLimits per PTG: minimum over the bands (eq. 6.4); the bands' cells are found once for all PTGs
        limits = self._spaces[0].tp_limits_all(self._spaces, xy, ptr)
        if self._view_limits is not None:  # what no sensor sees is not known to be free
            limits = [np.minimum(lim, cap) for lim, cap in zip(limits, self._view_limits, strict=True)]
        self._reapproach(stamp_s, T_odom_base, band_xy)
        target_index = self._reachable_target(T_odom_base, limits)
        T_base_odom = se2.inverse(T_odom_base)
        target_base = se2.transform_points(T_base_odom, self._waypoints[target_index][None])[0]
        self._update_stuck(stamp_s, T_odom_base)
        # Blocked goal: only points within a band's radius of the spot to stand on can touch the robot there
        goal_xy = self._waypoints[-1]
        if float(np.linalg.norm(goal_xy - T_odom_base[:2, 2])) <= cfg.blocked_check_m:
            spot_base = se2.transform_points(T_base_odom, self._goal_spot(T_odom_base)[None])[0]
            radius = np.full(n_bands, self._robot_radius_m + 1e-6)
            near_xy, near_ptr = points_near(xy, ptr, float(spot_base[0]), float(spot_base[1]), radius)
            near_band_xy = [near_xy[near_ptr[b]:near_ptr[b + 1]] for b in range(n_bands)]
        else:
            near_band_xy = band_xy  # not looked at: the goal is too far for the check
        if self._goal_is_blocked(T_odom_base, near_band_xy):
            return self._wait_for_goal(stamp_s, dt, t0, band_xy, target_index)
        self._goal_blocked_since_s = None
        # A doorway someone stands in: make room and wait until it frees up
        doorway = self._held_doorway(stamp_s, T_odom_base, band_xy)
        if doorway is not None:
            return self._yield(dt, t0, T_odom_base, xy, ptr, band_xy, doorway, target_index)
        # Candidates: one holonomic decision per PTG, then the best by eq. 6.5
        best, direct = self._best_candidate(target_base, limits, final=target_index == len(self._waypoints) - 1)
        # No path reaches a target far off the heading: turn in place towards it if the turning circle is free
        stalled = best is None or best.speed <= 0.0
        if self._should_turn(stamp_s, T_odom_base, target_base, direct, xy, ptr, stalled):
            self._blocked_since_s = None
            self._seam_side = 1 if math.copysign(1.0, float(target_base[1])) > 0 else -1
            return self._output(0.0, self._turn_rate(float(target_base[1]), band_xy), dt, t0, "turning", target_index)
        # Spun out on the spot: no more turning around; face the target and wait for a way towards it
        if self._spun_out() and best is not None and best.speed > 0.0 and \
                abs(index_to_alpha(best.k, self._spaces[best.ptg].num_paths)) > _SEAM_RAD:
            return self._face_target(dt, t0, target_base, xy, ptr, band_xy, target_index)
        recovering = self._blocked_since_s is not None and stamp_s - self._blocked_since_s < cfg.recovery_min_s
        squeeze = None
        if stalled and not recovering and cfg.squeeze and self._may_squeeze(T_odom_base):
            squeeze = self._squeeze_candidate(target_base, limits, band_xy)  # a doorway the grids close
        squeezing = squeeze is not None
        best = squeeze or best
        if best is None or best.speed <= 0.0 or recovering:
            if self._squeezing:  # squeezed in and stuck: not again from here
                self._squeeze_stuck_xy = T_odom_base[:2, 2].copy()
            self._squeezing = False
            return self._recover(stamp_s, dt, t0, T_odom_base, band_xy, target_index)
        self._squeezing = squeezing
        self._blocked_since_s = None
        space = self._spaces[best.ptg]
        v, w = space.command(best.k)
        at_seam = abs(index_to_alpha(best.k, space.num_paths)) > _SEAM_RAD
        self._seam_side = (1 if w > 0 else -1) if at_seam and w != 0.0 else 0
        speed = best.speed * self._approach_speed_factor(T_odom_base)
        speed *= self._point_speed_scale(v, w, self._obstacle_speed_factor(band_xy))
        v, w = self._limit_speeds(v * speed, w * speed)
        return self._output(v, w, dt, t0, "squeezing" if squeezing else "navigating", target_index, space.name,
                            best.k, best.free, speed)

    # ------------------------------------------------------------------------------------------- waypoints
    def _advance_waypoints(self, T_odom_base: np.ndarray) -> None:
        """Pass waypoints within their allowed distance (and faced at their heading, if they have one; else
        ``_aligning`` is set); the goal needs ``target_allowed_distance_m``."""
        xy = T_odom_base[:2, 2]
        yaw = math.atan2(T_odom_base[1, 0], T_odom_base[0, 0])
        self._aligning = False
        while self._target < len(self._waypoints):
            if np.linalg.norm(self._waypoints[self._target] - xy) > self._allowed_m[self._target]:
                break
            heading = self._headings[self._target]
            if np.isfinite(heading) and abs(se2.wrap_angle(heading - yaw)) > \
                    self.config.waypoint_heading_tolerance_rad:
                self._aligning = True
                break
            self._pass_waypoint()

    def _pass_waypoint(self) -> None:
        self._target += 1
        self._first_unpassed = self._target
        self._aligning = False
        self._best_distance, self._best_distance_stamp_s = math.inf, None

    def _alignment_turn(self, T_odom_base: np.ndarray, xy: np.ndarray, ptr: np.ndarray) -> float:
        """Yaw rate (rad/s) that turns the robot towards the current waypoint's heading, 0 when an obstacle of
        some band lies within that band's turning circle."""
        if not _circles_free(xy, ptr, self._turn_radii_m):
            return 0.0
        yaw = math.atan2(T_odom_base[1, 0], T_odom_base[0, 0])
        error = se2.wrap_angle(float(self._headings[self._target]) - yaw)
        return math.copysign(self.max_w_rad_s, error)

    def _reachable_target(self, T_odom_base: np.ndarray, limits: list[np.ndarray]) -> int:
        """The furthest waypoint within the horizon that some PTG reaches collision-free, else the current.

        Waypoints that may not be skipped stop the search: the robot goes through them. A waypoint skipped
        earlier (passed over for a later one that was reachable then, not driven past) is a candidate again while
        it lies ahead of the robot: when what made the later one reachable closes (someone steps into the way
        through a doorway), the robot aims at the waypoint in the doorway again instead of at a target beyond
        the wall. Nothing beyond the current waypoint is a candidate while the robot is short of a doorway it
        passed last (``through_doorway_first``)."""
        fixed = np.nonzero(~self._allow_skip[self._target:])[0]
        end = self._target + int(fixed[0]) if len(fixed) else len(self._waypoints) - 1
        if self._in_doorway_passed(T_odom_base):
            end = self._target
        ahead = np.arange(self._first_unpassed, end + 1)
        if len(ahead) <= 1 and self._first_unpassed == self._target:
            return self._target
        xy = se2.transform_points(se2.inverse(T_odom_base), self._waypoints[ahead])
        near = np.hypot(xy[:, 0], xy[:, 1]) < self.config.ref_distance_m
        near &= (ahead >= self._target) | (xy[:, 0] > 0.0)  # skipped ones only in front of the robot
        if not near.any():
            return self._target
        ahead, xy = ahead[near], xy[near]
        reachable = np.zeros(len(ahead), dtype=bool)
        if self._skip_view_limits is not None:  # no skipping through what no sensor sees (a wall behind it)
            limits = [np.minimum(lim, cap) for lim, cap in zip(limits, self._skip_view_limits, strict=True)]
        for space, lim in zip(self._spaces, limits, strict=True):
            k, d, exact = space.inverse_map_many(xy)
            reachable |= exact & (d <= 1.0) & (lim[k] > 1.01 * d)
        if reachable.any():
            self._target = int(ahead[np.nonzero(reachable)[0][-1]])
        return self._target

    def _reapproach(self, stamp_s: float, T_odom_base: np.ndarray, band_xy: list[np.ndarray]) -> None:
        """Aim again at the last waypoint passed, with its given allowed distance, if it has a heading (where the
        robot lines up before a doorway or a narrow node), the robot has not crossed the waypoint after it, has made
        no progress for ``reapproach_after_s`` while not yielding, and the robot standing on the waypoint at its
        heading would overlap no point now; once per waypoint. The time without progress runs on, so in the next
        steps the waypoint before it follows by the same rule: the robot goes back along its route through the
        waypoints with a heading whose next waypoint it has not crossed."""
        cfg, k = self.config, self._first_unpassed - 1
        if cfg.reapproach_after_s is None or k < 0 or k in self._reapproached or self._yielding or \
                self._best_distance_stamp_s is None or not np.isfinite(self._headings[k]) or \
                stamp_s - self._best_distance_stamp_s < cfg.reapproach_after_s or \
                not self._short_of(T_odom_base, k + 1) or \
                self._would_overlap(T_odom_base, self._waypoints[k], float(self._headings[k]), band_xy):
            return
        self._reapproached.add(k)
        self._target = self._first_unpassed = k
        self._allowed_m[k] = self._given_allowed_m[k]

    def _in_doorway_passed(self, T_odom_base: np.ndarray) -> bool:
        """Whether the last waypoint passed is a doorway (flagged ``give_way``, without a heading) the robot has not
        crossed yet (:meth:`_short_of`), with ``through_doorway_first``."""
        k = self._first_unpassed - 1
        return (self.config.through_doorway_first and k >= 0 and bool(self._give_way[k])
                and not np.isfinite(self._headings[k]) and self._short_of(T_odom_base, k))

    def _goal_spot(self, T_odom_base: np.ndarray) -> np.ndarray:
        """(2,) the nearest place to stand on that reaches the goal: the goal pulled towards the robot by
        ``target_allowed_distance_m`` (fixed frame, m)."""
        goal = self._waypoints[-1]
        offset = T_odom_base[:2, 2] - goal
        distance = float(np.linalg.norm(offset))
        if distance <= self.config.target_allowed_distance_m:
            return T_odom_base[:2, 2].copy()
        return goal + offset * (self.config.target_allowed_distance_m / distance)

    def _goal_is_blocked(self, T_odom_base: np.ndarray, band_xy: list[np.ndarray]) -> bool:
        """Whether the robot would overlap an obstacle standing on :meth:`_goal_spot`, facing the goal (someone
        stands on the goal: the robot stops in front of it instead of pressing on)."""
        goal = self._waypoints[-1]
        offset = goal - T_odom_base[:2, 2]
        if float(np.linalg.norm(offset)) > self.config.blocked_check_m:
            self._goal_blocked_steps = 0
            return False
        hit = self._would_overlap(T_odom_base, self._goal_spot(T_odom_base), math.atan2(offset[1], offset[0]),
                                  band_xy)
        self._goal_blocked_steps = self._goal_blocked_steps + 1 if hit else 0
        return self._goal_blocked_steps >= self.config.blocked_confirm_steps

    def _wait_for_goal(self, stamp_s: float, dt: float, t0: float, band_xy: list[np.ndarray],
                       target_index: int) -> NavCommand:
        """In front of a taken goal: stop and wait, and after every ``recovery_retry_s`` of waiting make room,
        backing away slowly for ``recovery_duration_s`` while the space behind is free (someone in a doorway who
        waits to come out past the robot stands on the spot the robot waits for)."""
        cfg = self.config
        if self._goal_blocked_since_s is None:
            self._goal_blocked_since_s = stamp_s
        phase = (stamp_s - self._goal_blocked_since_s) % (cfg.recovery_retry_s + cfg.recovery_duration_s)
        if phase >= cfg.recovery_retry_s and self._behind_is_free(band_xy):
            return self._output(-cfg.recovery_speed_m_s, 0.0, dt, t0, "blocked", target_index)
        return self._output(0.0, 0.0, dt, t0, "blocked", target_index)

    def _held_doorway(self, stamp_s: float, T_odom_base: np.ndarray, band_xy: list[np.ndarray]) -> int | None:
        """The index of the doorway the robot yields at now, or None (see ``NavigatorConfig.give_way``): the current
        waypoint or the one after it, else (``give_way_until_crossed``) the last one passed but not crossed yet
        (:meth:`_short_of`), flagged ``give_way``, its doorway within ``give_way_check_m``
        (:meth:`_doorway_distance_m`), whose spot (facing from the waypoint before it) has been taken for
        ``blocked_confirm_steps`` steps, and held until it has been free for ``give_way_clear_s``."""
        cfg = self.config
        ahead = [k for k in (self._target, self._target + 1) if k < len(self._waypoints) - 1 and self._give_way[k]]
        short = [k for k in range(max(self._target - _DOORWAY_RUN, 0), self._target)
                 if self._give_way[k] and self._short_of(T_odom_base, k)] if cfg.give_way_until_crossed else []
        k = ahead[0] if ahead else short[-1] if short else -1
        if not cfg.give_way or k < 0 or self._doorway_distance_m(T_odom_base, k) > cfg.give_way_check_m:
            self._held_steps, self._yielding, self._doorway_clear_since_s = 0, False, None
            return None
        spot = self._waypoints[k]
        before = self._waypoints[k - 1] if k > 0 else T_odom_base[:2, 2]
        heading = math.atan2(spot[1] - before[1], spot[0] - before[0])
        taken = self._would_overlap(T_odom_base, spot, heading, band_xy)
        self._held_steps = self._held_steps + 1 if taken else 0
        if self._held_steps >= cfg.blocked_confirm_steps:
            self._yielding, self._doorway_clear_since_s = True, None
        elif self._yielding and not taken:
            if self._doorway_clear_since_s is None:
                self._doorway_clear_since_s = stamp_s
            self._yielding = stamp_s - self._doorway_clear_since_s < cfg.give_way_clear_s
        return k if self._yielding else None

    def _short_of(self, T_odom_base: np.ndarray, k: int) -> bool:
        """Whether the robot has not yet crossed waypoint ``k`` (> 0): it lies behind the line through the
        waypoint square to the route's leg from waypoint ``k - 1`` (a waypoint is passed up to its allowed distance
        before it)."""
        if k == 0:
            return False
        leg = self._waypoints[k] - self._waypoints[k - 1]
        return float(np.dot(T_odom_base[:2, 2] - self._waypoints[k], leg)) < 0.0

    def _doorway_distance_m(self, T_odom_base: np.ndarray, doorway: int) -> float:
        """Distance from the robot to the nearest flagged waypoint of the doorway that ends at waypoint ``doorway``
        (itself and the flagged ones up to ``_DOORWAY_RUN`` before it), m."""
        run = np.arange(max(doorway - _DOORWAY_RUN, 0), doorway + 1)
        run = run[self._give_way[run]]
        return float(np.min(np.hypot(*(self._waypoints[run] - T_odom_base[:2, 2]).T)))

    def _yield(self, dt: float, t0: float, T_odom_base: np.ndarray, xy: np.ndarray, ptr: np.ndarray,
               band_xy: list[np.ndarray], doorway: int, target_index: int) -> NavCommand:
        """Before a held doorway: back away straight while facing it, nearer than ``give_way_distance_m`` to it or
        to a flagged waypoint just before it (a doorway can be a run of narrow waypoints: the robot standing in the
        first while someone holds the next one still blocks their way out), the space behind is free and, with
        ``give_way_on_trail``, on the robot's own trail; else stop. Off its trail, with ``give_way_turn_back``, it
        first turns in place, the turning circle free, to a heading it came here with (:meth:`_trail_turn`) that
        keeps the doorway ahead."""
        cfg = self.config
        spot_base = se2.transform_points(se2.inverse(T_odom_base), self._waypoints[doorway][None])[0]
        self._turning, self._blocked_since_s = False, None
        if float(spot_base[0]) <= 0.0 or self._doorway_distance_m(T_odom_base, doorway) >= cfg.give_way_distance_m:
            return self._output(0.0, 0.0, dt, t0, "yielding", target_index)
        # Back straight while the space behind is free (and on the trail)
        if self._behind_is_free(band_xy) and (not cfg.give_way_on_trail or self._behind_is_trail(T_odom_base, True)
                                              or self._behind_seen_free(T_odom_base)):
            return self._output(-cfg.give_way_speed_m_s, 0.0, dt, t0, "yielding", target_index)
        # Off the trail: turn back towards a heading the robot came here with
        if cfg.give_way_on_trail and cfg.give_way_turn_back and _circles_free(xy, ptr, self._turn_radii_m):
            turn = self._trail_turn(T_odom_base, math.atan2(float(spot_base[1]), float(spot_base[0])))
            if turn is not None:  # slowing down into the heading: no overshoot that turns the doorway out of view
                w = math.copysign(min(abs(self._turn_rate(turn, band_xy)), _HEADING_GAIN_1_S * abs(turn)), turn)
                return self._output(0.0, w, dt, t0, "yielding", target_index)
        return self._output(0.0, 0.0, dt, t0, "yielding", target_index)

    def _lineup_spot_taken(self, T_odom_base: np.ndarray, band_xy: list[np.ndarray]) -> bool:
        """Whether the current waypoint (not the goal) has a heading, lies within ``taken_waypoint_pass_m`` and the
        robot standing on it at that heading would overlap an obstacle point, for ``blocked_confirm_steps`` steps
        in a row (an open door leaf beside a doorway's approach waypoint leaves no room to stand there)."""
        k = self._target
        spot, heading = self._waypoints[k], float(self._headings[k])
        if k >= len(self._waypoints) - 1 or not math.isfinite(heading) or \
                float(np.linalg.norm(spot - T_odom_base[:2, 2])) > self.config.taken_waypoint_pass_m:
            self._spot_taken_steps = 0
            return False
        hit = self._would_overlap(T_odom_base, spot, heading, band_xy)
        self._spot_taken_steps = self._spot_taken_steps + 1 if hit else 0
        return self._spot_taken_steps >= self.config.blocked_confirm_steps

    def _would_overlap(self, T_odom_base: np.ndarray, spot_xy: np.ndarray, yaw_rad: float,
                       band_xy: list[np.ndarray]) -> bool:
        """Whether the robot's true sections, standing at ``spot_xy`` (fixed frame, m) facing ``yaw_rad``, would
        contain a point of ``band_xy`` (per band, base frame at ``T_odom_base``)."""
        from simnav.navigation.collision_grid import points_in_polygon

        T_spot_base = se2.inverse(se2.inverse(T_odom_base) @ se2.from_xy_yaw(spot_xy[0], spot_xy[1], yaw_rad))
        return any(len(pts) and np.any(points_in_polygon(se2.transform_points(T_spot_base, pts), band.polygon))
                   for band, pts in zip(self.bands, band_xy, strict=True))

    def _update_stuck(self, stamp_s: float, T_odom_base: np.ndarray) -> None:
        """Progress towards the furthest waypoint aimed at so far (a route may lead away from the goal for a while;
        aiming back at a skipped waypoint does not restart the timer)."""
        if self._target > self._progress_target:  # not back to a skipped waypoint: that would reset the timer
            self._progress_target, self._best_distance_stamp_s = self._target, None
        d = float(np.linalg.norm(self._waypoints[self._progress_target] - T_odom_base[:2, 2]))
        if self._best_distance_stamp_s is None:  # a new waypoint (or route: the kept time without progress)
            since_s = stamp_s if self._stuck_since_kept_s is None else self._stuck_since_kept_s
            self._best_distance, self._best_distance_stamp_s, self._stuck_since_kept_s = d, since_s, None
        elif d < self._best_distance - self.config.stuck_progress_m:
            self._best_distance, self._best_distance_stamp_s = d, stamp_s

    # ------------------------------------------------------------------------------------------ candidates
    def _best_candidate(self, target_base: np.ndarray, limits: list[np.ndarray],
                        final: bool) -> tuple[_Candidate | None, bool]:
        """The best candidate (None when every PTG is blocked) and whether some PTG's path to the target is free
        all the way to it (or to the horizon)."""
        best, direct = self._candidates(target_base, limits, final, self._holonomic)
        if best is None and self._fallback is not None:  # ND found no way: a lower floor for its gap search
            best, _ = self._candidates(target_base, limits, final, self._fallback)
        return best, direct

    def _may_squeeze(self, T_odom_base: np.ndarray) -> bool:
        """Whether a waypoint flagged ``give_way`` (a doorway) among the ``_DOORWAY_RUN`` before and after the
        current one lies within ``squeeze_reach_m`` of the robot, and the robot is ``recovery_clearance_m`` or more
        from where squeezing last ended with every path blocked (else it squeezes in and backs out in turn)."""
        xy = T_odom_base[:2, 2]
        if self._squeeze_stuck_xy is not None and \
                float(np.linalg.norm(xy - self._squeeze_stuck_xy)) < self.config.recovery_clearance_m:
            return False
        lo, hi = max(self._target - _DOORWAY_RUN, 0), min(self._target + _DOORWAY_RUN, len(self._waypoints) - 1)
        run = np.arange(lo, hi + 1)
        run = run[self._give_way[run]]
        return bool(len(run)) and float(np.min(np.hypot(*(self._waypoints[run] - xy).T))) <= \
            self.config.squeeze_reach_m

    def _squeeze_candidate(self, target_base: np.ndarray, limits: list[np.ndarray],
                           band_xy: list[np.ndarray]) -> _Candidate | None:
        """For a target within ``_SQUEEZE_BEARING_RAD`` of the heading, the target's own path of the first PTG that
        reaches it within ``squeeze_reach_m``, whose grids block it more than ``secure_distance_m`` short of it (an
        obstacle just beyond is no gap) and whose exact sweep up to it is free (:meth:`_sweep_is_free`), at
        ``squeeze_speed_m_s``; None if there is none (squeezing towards a target further on, the robot crept along
        an open door leaf in the office, then squeezed and backed out in turn)."""
        cfg = self.config
        if abs(math.atan2(float(target_base[1]), float(target_base[0]))) > _SQUEEZE_BEARING_RAD:
            return None  # a gap ahead, not a way round
        for i, (space, lim) in enumerate(zip(self._spaces, limits, strict=True)):
            k_t, d_t, _ = space.inverse_map(float(target_base[0]), float(target_base[1]))
            if d_t * cfg.ref_distance_m > cfg.squeeze_reach_m or \
                    (d_t - float(lim[k_t])) * cfg.ref_distance_m <= cfg.secure_distance_m or \
                    not self._sweep_is_free(space, k_t, d_t, band_xy):
                continue
            v, w = space.command(k_t)
            path_m_s = math.hypot(v, w * space.ptg.config.turning_radius_ref_m)
            speed = min(self._stopping_speed(space, k_t, d_t), cfg.squeeze_speed_m_s / max(path_m_s, 1e-9))
            if speed > 0.0:
                return _Candidate(i, k_t, speed, d_t, 0.0)
        return None

    def _sweep_is_free(self, space, k: int, d_norm: float, band_xy: list[np.ndarray]) -> bool:
        """Whether the robot's sections grown by ``squeeze_margin_m``, moved along path k of ``space`` up to the
        normalised distance ``d_norm`` (the PTG's stored poses, 1.5 cm apart, and the end pose), contain none of
        ``band_xy`` (per band, base frame, m)."""
        ptg = space.ptg
        n = ptg.step_for_distance(k, d_norm * ptg.ref_distance_m) + 1
        poses = np.vstack([ptg.poses[k, :n], ptg.pose_at(k, d_norm)[None]])
        reach_m = d_norm * ptg.ref_distance_m
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        for polygon, radius, pts in zip(self._squeeze_polygons, self._squeeze_radii_m, band_xy, strict=True):
            pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= reach_m + radius]
            if len(pts) == 0:
                continue
            dx, dy = pts[None, :, 0] - poses[:, 0, None], pts[None, :, 1] - poses[:, 1, None]
            local = np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)
            if np.any(points_in_polygon(local, polygon)):
                return False
        return True

    def _candidates(self, target_base: np.ndarray, limits: list[np.ndarray], final: bool,
                    methods: list) -> tuple[_Candidate | None, bool]:
        """:meth:`_best_candidate` with one holonomic method per PTG (``methods``)."""
        cfg = self.config
        best: _Candidate | None = None
        direct = False
        for i, (space, lim) in enumerate(zip(self._spaces, limits, strict=True)):
            k_t, d_t, exact = space.inverse_map(float(target_base[0]), float(target_base[1]))
            on_path = exact or d_t >= 1.0  # a path reaches the target, or heads for it beyond the horizon
            direct = direct or (on_path and float(lim[k_t]) >= min(d_t + 0.01, 1.0))
            hol = HolonomicInput.toward_path(lim, k_t, d_t, ref_distance_m=cfg.ref_distance_m,
                                             slow_down_near_target=final)
            decision = methods[i].navigate(hol)
            choices = [(self._keep_seam_side(space, int(decision.direction_k), lim, target_base),
                        float(decision.speed))]
            if exact and int(decision.direction_k) != k_t and float(lim[k_t]) >= d_t + 0.01:
                # the target's own path, free up to the target: a doorway that only this path passes is a gap
                # too narrow for ND's filters (they ask for ceil(1% N) paths, or ±ceil(2% N) to go straight)
                nearness = hol.target_nearness(_ND.target_slow_approaching_distance_m)
                choices.append((k_t, _target_path_speed(lim, k_t) * nearness))
            for k, speed in choices:
                free = float(lim[k])
                speed = min(speed, self._stopping_speed(space, k, free))
                if speed <= 0.0:
                    continue
                score = self._score(space, k, free, k_t, d_t, target_base, on_path)
                if best is None or score > best.score:
                    best = _Candidate(i, k, speed, free, score)
        return best, direct

    def _keep_seam_side(self, space, k: int, lim: np.ndarray, target_base: np.ndarray) -> int:
        """Path k, or its mirror image when k lies at the seam of TP-space and turns the other way.

        ND sees the valley behind the robot, across alpha = +-pi, as two gaps (as MRPT's does), and which one wins
        flips as the robot turns; a path at the seam (``|alpha| > _SEAM_RAD``) and its mirror (``k <-> N-1-k``)
        head for the same region behind the robot, turning opposite ways. While the mirror is nearly as free
        (90 %), the robot keeps turning the way it already turns at the seam, else towards the target's side.
        """
        n = space.num_paths
        if abs(index_to_alpha(k, n)) <= _SEAM_RAD:
            return k
        side = self._seam_side or (1 if target_base[1] >= 0.0 else -1)
        if math.copysign(1.0, space.command(k)[1]) == side:
            return k
        mirror = n - 1 - k
        return mirror if float(lim[mirror]) >= 0.9 * float(lim[k]) else k

    def _should_turn(self, stamp_s: float, T_odom_base: np.ndarray, target_base: np.ndarray, direct: bool,
                     xy: np.ndarray, ptr: np.ndarray, stalled: bool = False) -> bool:
        """Turn in place: no path reaches the target, it lies beyond ``turn_in_place_start_rad`` off the heading
        (once turning: beyond ``turn_in_place_stop_rad``), no obstacle of any band is within the band's turning
        circle (its section's circumradius plus the footprint margin) and, to start, the last turn in place is
        ``turn_in_place_retry_s`` or ``turn_in_place_retry_m`` away, unless no path moves (``stalled``): turning
        beats waiting, and then the turning circle needs only ``_TIGHT_TURN_MARGIN_M`` of margin (a robot that
        stopped 4 cm from an open door leaf, every path blocked, waited there for ever) and the target only lies
        beyond ``turn_in_place_stalled_rad`` (a robot facing a door jamb 40 degrees off its target waited there)."""
        cfg = self.config
        x, y = float(T_odom_base[0, 2]), float(T_odom_base[1, 2])
        if not cfg.turn_in_place:
            return False
        if not self._turning and self._turn_end is not None and not stalled:
            t_end, x_end, y_end = self._turn_end
            if stamp_s - t_end < cfg.turn_in_place_retry_s and math.hypot(x - x_end, y - y_end) < \
                    cfg.turn_in_place_retry_m:
                return False
        bearing = abs(math.atan2(float(target_base[1]), float(target_base[0])))
        if stalled:
            threshold = cfg.turn_in_place_stalled_rad
        else:
            threshold = cfg.turn_in_place_stop_rad if self._turning else cfg.turn_in_place_start_rad
        radii = self._tight_turn_radii_m if stalled else self._turn_radii_m
        turning = not direct and bearing > threshold and _circles_free(xy, ptr, radii)
        if self._turning and not turning:
            self._turn_end = (stamp_s, x, y)
        self._turning = turning
        return turning

    def _score(self, space, k: int, free: float, k_t: int, d_t: float, target_base: np.ndarray,
               on_path: bool = True) -> float:
        """Eq. 6.5 with the factors of §6.C.5 (as MRPT's scalarisation: larger is better); ``on_path``: whether a
        path of this PTG reaches the target (else ``d_t`` is the cost of a continuation off the PTG's paths)."""
        cfg = self.config
        n = space.num_paths
        # f1: collision-free distance (saturates once the path reaches the target)
        f1 = 1.0 if on_path and free > d_t + 0.05 else free
        # f2: TP-angle between candidate and target, circular in k
        dk = abs(k - k_t)
        f2 = math.exp(-min(dk, n - dk) / (n / 10.0))
        # f3: closest approach of the path (up to its free distance) to the target
        d_min = space.closest_approach(k, min(free, 0.99 * d_t if d_t > 0 else free), target_base)
        f3 = 1.0 / (1.0 + d_min**2)
        # f4: similarity to the previous command
        v, w = space.command(k)
        v0, w0 = self._last_cmd
        f4 = min(math.exp(-abs(v - v0) / (0.2 * self.max_v_m_s)), math.exp(-abs(w - w0) / (0.2 * self.max_w_rad_s)))
        # reaching the target within the free distance (along a path of this PTG)
        e = max(0.0, d_t)
        f0 = 1.0 / (1.0 + e**2) if on_path and free > e else 0.0
        score = (cfg.weight_free_distance * f1 + cfg.weight_target_angle * f2 + cfg.weight_target_nearness * f3
                 + cfg.weight_hysteresis * f4 + cfg.weight_target_distance * f0)
        return score * (cfg.backward_priority if space.backward else 1.0)

    # -------------------------------------------------------------------------------------- speed regulation
    def _stopping_speed(self, space, k: int, free: float) -> float:
        """The secure-distance ramp: the relative speed (0..1) on path k from which the robot stops
        ``secure_distance_m`` short of the path's first obstacle, ``free`` (normalised) along it: reacting for
        ``reaction_time_s``, then braking at ``braking_m_s2`` (distances in the PTG's pseudo-metres)."""
        cfg = self.config
        room_m = free * cfg.ref_distance_m - cfg.secure_distance_m
        if room_m <= 0.0:
            return 0.0
        a, tau = cfg.braking_m_s2, cfg.reaction_time_s
        allowed_m_s = a * (math.sqrt(tau * tau + 2.0 * room_m / a) - tau)
        v, w = space.command(k)
        path_m_s = math.hypot(v, w * space.ptg.config.turning_radius_ref_m)
        return 1.0 if path_m_s <= allowed_m_s else allowed_m_s / path_m_s

    def _obstacle_speed_factor(self, band_xy: list[np.ndarray]) -> float:
        """Slow down near obstacles; an obstacle ahead counts fully, one to the side ``lateral_obstacle_weight``.

        The distance of a point is its distance to the bounding box of its own band's section (one Numba pass over
        each band's points, :func:`~simnav.navigation.binning.effective_obstacle_distance`; distances beyond
        ``slow_down_distance_m`` all give full speed, so the search starts from there)."""
        cfg = self.config
        effective = cfg.slow_down_distance_m
        for (lo, hi), pts in zip(self._band_boxes, band_xy, strict=True):
            if len(pts):
                effective = effective_obstacle_distance(np.ascontiguousarray(pts, dtype=np.float64), float(lo[0]),
                                                        float(lo[1]), float(hi[0]), float(hi[1]),
                                                        cfg.lateral_obstacle_weight, effective)
        ramp = (effective - cfg.stop_distance_m) / (cfg.slow_down_distance_m - cfg.stop_distance_m)
        return float(np.clip(ramp, cfg.min_speed_near_obstacles, 1.0))

    def _point_speed_scale(self, v: float, w: float, factor: float) -> float:
        """Scale (<= 1) of a path's full-speed command (v, w) that keeps the robot's fastest point,
        ``|v| + |w|·circumradius``, at or below ``factor`` of the top speed: near obstacles a drive slows down in
        proportion, while a turn on the spot, which brings no point fast towards them, keeps most of its rate."""
        if factor >= 1.0:
            return 1.0
        point_m_s = abs(v) + abs(w) * self._robot_radius_m
        cap_m_s = factor * self.max_v_m_s
        return 1.0 if point_m_s <= cap_m_s else cap_m_s / point_m_s

    def _approach_speed_factor(self, T_odom_base: np.ndarray) -> float:
        """Slow down over ``target_slow_down_m`` before the final target."""
        cfg = self.config
        d = float(np.linalg.norm(self._waypoints[-1] - T_odom_base[:2, 2]))
        return float(np.clip(cfg.target_min_speed + (1 - cfg.target_min_speed) * d / cfg.target_slow_down_m,
                             0.0, 1.0))

    def _limit_speeds(self, v: float, w: float) -> tuple[float, float]:
        """Clamp (v, w) to the robot's limits together, which keeps the path's curvature."""
        scale = max(abs(v) / self.max_v_m_s, abs(w) / self.max_w_rad_s, 1.0)
        return v / scale, w / scale

    def _accelerate(self, v: float, w: float, dt: float) -> tuple[float, float]:
        """Acceleration-limited change from the previous command."""
        acc_v, acc_w = self._acc
        v0, w0 = self._last_cmd
        if acc_v is not None and dt > 0:
            v = v0 + float(np.clip(v - v0, -acc_v * dt, acc_v * dt))
        if acc_w is not None and dt > 0:
            w = w0 + float(np.clip(w - w0, -acc_w * dt, acc_w * dt))
        return v, w

    # --------------------------------------------------------------------------------------------- recovery
    def _recover(self, stamp_s: float, dt: float, t0: float, T_odom_base: np.ndarray, band_xy: list[np.ndarray],
                 target_index: int) -> NavCommand:
        """Every path blocked: back away slowly while the space behind is free, then stop and wait (§6.C.6); after
        ``recovery_retry_s`` of waiting, back away again."""
        cfg = self.config
        if self._blocked_since_s is None or \
                stamp_s - self._blocked_since_s >= cfg.recovery_duration_s + cfg.recovery_retry_s:
            self._blocked_since_s = stamp_s
        if (stamp_s - self._blocked_since_s < cfg.recovery_duration_s and self._behind_is_free(band_xy)
                and self._behind_is_trail(T_odom_base)):
            return self._output(-cfg.recovery_speed_m_s, 0.0, dt, t0, "recovering", target_index)
        return self._output(0.0, 0.0, dt, t0, "waiting", target_index)

    def _update_spin(self, T_odom_base: np.ndarray) -> None:
        """Add up how much the robot has turned since it last moved ``_SPIN_RESET_M`` away."""
        x, y = float(T_odom_base[0, 2]), float(T_odom_base[1, 2])
        yaw = math.atan2(T_odom_base[1, 0], T_odom_base[0, 0])
        if self._spin is None or math.hypot(x - self._spin[0], y - self._spin[1]) > _SPIN_RESET_M:
            self._spin = (x, y, yaw, 0.0)
            return
        self._spin = (self._spin[0], self._spin[1], yaw, self._spin[3] + abs(se2.wrap_angle(yaw - self._spin[2])))

    def _spun_out(self) -> bool:
        """Whether the robot has turned more than ``spin_limit_rad`` on the spot."""
        limit = self.config.spin_limit_rad
        return limit is not None and self._spin is not None and self._spin[3] > limit

    def _face_target(self, dt: float, t0: float, target_base: np.ndarray, xy: np.ndarray, ptr: np.ndarray,
                     band_xy: list[np.ndarray], target_index: int) -> NavCommand:
        """Turn in place towards the target (base frame, m) the short way while it lies beyond
        ``turn_in_place_stop_rad`` and the turning circle is free; else stop (state ``waiting``)."""
        bearing = math.atan2(float(target_base[1]), float(target_base[0]))
        if abs(bearing) > self.config.turn_in_place_stop_rad and _circles_free(xy, ptr, self._tight_turn_radii_m):
            return self._output(0.0, self._turn_rate(bearing, band_xy), dt, t0, "turning", target_index)
        return self._output(0.0, 0.0, dt, t0, "waiting", target_index)

    def _turn_rate(self, side: float, band_xy: list[np.ndarray]) -> float:
        """Yaw rate (rad/s) to turn in place towards ``side`` (> 0: left), slowed near obstacles."""
        w = math.copysign(self.max_w_rad_s, side)
        return w * self._point_speed_scale(0.0, w, self._obstacle_speed_factor(band_xy))

    def _behind_is_free(self, band_xy: list[np.ndarray]) -> bool:
        """Whether no sensed or remembered point lies where any band's section slides straight back by
        ``recovery_clearance_m``."""
        reach = self.config.recovery_clearance_m
        for band, pts in zip(self.bands, band_xy, strict=True):
            if len(pts) == 0:
                continue
            x_min = float(np.min(band.polygon[:, 0]))
            y_lo, y_hi = float(np.min(band.polygon[:, 1])), float(np.max(band.polygon[:, 1]))
            behind = (pts[:, 0] < x_min) & (pts[:, 0] > x_min - reach) & (pts[:, 1] > y_lo) & (pts[:, 1] < y_hi)
            if np.any(behind):
                return False
        return True

    def _behind_seen_free(self, T_odom_base: np.ndarray) -> bool:
        """Whether the robot's outline moved straight back by ``recovery_clearance_m``, where it lies outside the
        outline now, lies where the lidar saw free space (``give_way_seen_free_s``)."""
        if self._scans is None or len(self._scans) == 0:
            return False
        back = self._hull_samples_xy - (self.config.recovery_clearance_m, 0.0)
        back = back[~points_in_polygon(back, self._hull_xy)]
        return bool(np.all(self._scans.seen_free(se2.transform_points(T_odom_base, back))))

    def _remember_pose(self, stamp_s: float, T_odom_base: np.ndarray) -> None:
        """Keep the poses of the last ``recovery_trail_s`` seconds, one per 2 cm or 3 degrees of motion."""
        x, y = float(T_odom_base[0, 2]), float(T_odom_base[1, 2])
        yaw = math.atan2(T_odom_base[1, 0], T_odom_base[0, 0])
        trail = self._trail
        if not trail or math.hypot(x - trail[-1][1], y - trail[-1][2]) >= _TRAIL_STEP_M \
                or abs(se2.wrap_angle(yaw - trail[-1][3])) >= _TRAIL_STEP_RAD:
            trail.append((stamp_s, x, y, yaw))
        while trail and trail[0][0] < stamp_s - self.config.recovery_trail_s:
            trail.popleft()

    def _behind_is_trail(self, T_odom_base: np.ndarray, footprint: bool = False) -> bool:
        """Whether the robot, moved straight back by ``recovery_clearance_m``, stands where it stood recently with
        about the same heading (:meth:`_backs_onto_trail`; ``footprint``: its footprint where it was)."""
        yaw = math.atan2(T_odom_base[1, 0], T_odom_base[0, 0])
        return bool(self._trail) and bool(self._backs_onto_trail(np.array(self._trail), T_odom_base[:2, 2],
                                                                   np.array([yaw]), footprint)[0])

    def _backs_onto_trail(self, trail: np.ndarray, xy: np.ndarray, yaws_rad: np.ndarray,
                          footprint: bool = False) -> np.ndarray:
        """(H,) bool: whether a robot at ``xy`` (fixed frame, m) facing each of ``yaws_rad`` (H,), moved straight
        back by ``recovery_clearance_m``, stands within 0.1 m and 20 degrees of a pose of ``trail`` (N, 4), or,
        with ``footprint``, where it stood at one: every vertex of its bands' sections within
        ``footprint_margin_m`` of where that vertex was."""
        reach = self.config.recovery_clearance_m
        back_x, back_y = xy[0] - reach * np.cos(yaws_rad), xy[1] - reach * np.sin(yaws_rad)
        dist = np.hypot(trail[None, :, 1] - back_x[:, None], trail[None, :, 2] - back_y[:, None])  # (H, N)
        if not footprint:
            aligned = np.abs(se2.wrap_angle(trail[None, :, 3] - yaws_rad[:, None])) <= math.radians(20)
            return np.any((dist <= 0.1) & aligned, axis=1)
        # vertex offsets (p_b - p_t) + (R_b - R_t) c of every outline vertex c, for the pairs whose centres are near
        tol = self.config.footprint_margin_m
        h, n = np.nonzero(dist <= tol)
        dc, ds = np.cos(yaws_rad[h]) - np.cos(trail[n, 3]), np.sin(yaws_rad[h]) - np.sin(trail[n, 3])
        cx, cy = self._outline_xy[:, 0], self._outline_xy[:, 1]
        dx = (back_x[h] - trail[n, 1])[:, None] + dc[:, None] * cx - ds[:, None] * cy
        dy = (back_y[h] - trail[n, 2])[:, None] + ds[:, None] * cx + dc[:, None] * cy
        hits = np.zeros(len(yaws_rad), dtype=bool)
        hits[h[np.max(dx * dx + dy * dy, axis=1) <= tol * tol]] = True
        return hits

    def _trail_turn(self, T_odom_base: np.ndarray, doorway_bearing_rad: float) -> float | None:
        """The smallest turn in place (rad, > 0: left) to a heading of a trail pose within 0.1 m of the robot from
        which backing lands on the trail (:meth:`_backs_onto_trail`) and the doorway, now at
        ``doorway_bearing_rad`` in the base frame, stays within ``_DOORWAY_IN_VIEW_RAD`` of the heading; None if
        there is none."""
        if not self._trail:
            return None
        trail = np.array(self._trail)
        xy = T_odom_base[:2, 2]
        yaws = trail[np.hypot(trail[:, 1] - xy[0], trail[:, 2] - xy[1]) <= 0.1, 3]
        turns = se2.wrap_angle(yaws - math.atan2(T_odom_base[1, 0], T_odom_base[0, 0]))
        ok = (np.abs(se2.wrap_angle(doorway_bearing_rad - turns)) < _DOORWAY_IN_VIEW_RAD) & \
            self._backs_onto_trail(trail, xy, yaws, footprint=True)
        return float(turns[ok][np.argmin(np.abs(turns[ok]))]) if np.any(ok) else None

    # ---------------------------------------------------------------------------------------------- output
    def _output(self, v: float, w: float, dt: float, t0: float, state: str, target_index: int = -1, ptg: str = "",
                k: int = -1, free: float = 0.0, speed: float = 0.0) -> NavCommand:
        v, w = self._accelerate(v, w, dt)
        self._last_cmd = (v, w)
        stuck = (self._best_distance_stamp_s is not None and self._last_stamp_s is not None
                 and self._last_stamp_s - self._best_distance_stamp_s > self.config.stuck_timeout_s
                 and state not in ("reached", "idle"))
        return NavCommand(v, w, state, stuck, target_index, ptg, k, free, speed, time.perf_counter() - t0)


_ND = NDConfig()
_SEAM_RAD = math.radians(135.0)  # paths beyond this |alpha| lie at the seam of TP-space (see _keep_seam_side)
_SQUEEZE_BEARING_RAD = math.radians(30.0)  # squeezing only towards a target this close to the heading: a gap ahead
_TIGHT_TURN_MARGIN_M = 0.02  # clearance of the turning circle when turning in place is all the robot can do


def _view_limits(space, view: Sequence[ViewSector], bands: Sequence[Band]) -> np.ndarray:
    """(N,) per path of ``space``, the normalised distance up to which its reference point stays in view of a
    sensor (or inside one of the robot's sections, where the robot stands now); 1 when it never leaves."""
    ptg = space.ptg
    n, s = ptg.dist_m.shape
    xy = ptg.poses[..., :2].reshape(-1, 2)
    seen = np.zeros(len(xy), dtype=bool)
    for sector in view:
        seen |= sector.contains(xy)
    for band in bands:
        seen |= points_in_polygon(xy, band.polygon)
    seen = seen.reshape(n, s) | (np.arange(s)[None, :] >= ptg.num_samples[:, None])
    out = np.ones(n)
    for k in np.nonzero(~seen.all(axis=1))[0]:
        first = int(np.argmin(seen[k]))
        out[k] = ptg.dist_m[k, max(first - 1, 0)] / ptg.ref_distance_m
    return out


def _scan_origin_xy(view: Sequence[ViewSector] | None) -> tuple[float, float]:
    """Where a level lidar's rays start in the base frame: the apex of the widest view sector (m), else the base
    origin."""
    if not view:
        return (0.0, 0.0)
    widest = max(view, key=lambda sector: sector.half_angle_rad)
    return (widest.x_m, widest.y_m)


def _circles_free(xy: np.ndarray, ptr: np.ndarray, radii_m: np.ndarray) -> bool:
    """Whether no obstacle point of any band lies within that band's circle (radius ``radii_m[b]``) around the base
    origin: the robot can turn in place."""
    return len(points_near(xy, ptr, 0.0, 0.0, radii_m)[0]) == 0


def _target_path_speed(lim: np.ndarray, k_t: int) -> float:
    """Relative speed along the target's own path k_t, by ND's risk rule (mean TP-obstacle within
    ``risk_evaluation_sectors_percent`` of N paths over ``risk_evaluation_distance``, at most 1)."""
    n = lim.shape[0]
    half = int(math.floor(_ND.risk_evaluation_sectors_percent * n + 0.5))
    risk = float(np.mean(lim[max(k_t - half, 0):min(k_t + half, n - 1) + 1]))
    return min(1.0, risk / _ND.risk_evaluation_distance)


_SPIN_RESET_M = 0.3  # turning adds up towards spin_limit_rad until the robot is this far from where it began, m
_DOORWAY_RUN = 3  # flagged waypoints this many before the held one belong to the same doorway (route_waypoints
# puts a leave waypoint and an approach waypoint between two narrow nodes in a row)
_TRAIL_STEP_M = 0.02
_TRAIL_STEP_RAD = math.radians(3)
_DOORWAY_IN_VIEW_RAD = math.radians(60)  # yielding turns back onto the trail only while the doorway stays this close
_SEEN_FREE_CLEARANCE_M = 0.3  # yielding backs off its trail only where it keeps this far from what the lidar saw
_HEADING_GAIN_1_S = 2.0  # yaw rate per radian left to turn when turning to a heading, 1/s

"""Moving things of a simulated office: walking people, wandering robots and swinging door leaves.

Pure numpy/scipy. World frame (x/y on the floor), SI units. The simulator copies the positions computed here
into MuJoCo mocap bodies and reads the velocities kept here as ground truth.
"""

from simnav.agents.crowd import Crowd
from simnav.agents.doors import DoorLeaf, door_segments
from simnav.agents.roadmap import RoadmapGraph
from simnav.agents.social_force import SocialForceParams
from simnav.agents.wanderers import Wanderers

__all__ = ["Crowd", "DoorLeaf", "RoadmapGraph", "SocialForceParams", "Wanderers", "door_segments"]

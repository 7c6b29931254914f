"""Missions: driving a robot through a world and recording or reporting what happened."""

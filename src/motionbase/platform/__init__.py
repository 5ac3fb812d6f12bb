"""Kinematics of the motion platforms: the 6-RUS rotary platform and the planar 3-RRR robot."""

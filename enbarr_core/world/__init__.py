"""The simulated world: obstacles as functions of time, and the profile's ``world`` section.

Pure (no ROS): ``model`` (``World``, its shapes and motions, ray casts and distances) and
``parse`` (``parse_world``). Nodes get the profile's world as ``EnbarrNode.world``.
"""

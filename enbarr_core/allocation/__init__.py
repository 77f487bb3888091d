"""Allocation: from a generalized force to what each actuator is commanded.

Pure: ``fixed`` (fixed thrusters), ``azimuth`` (azimuths, PWM calibration), ``least_norm``.
Parameters: ``layout_params`` (thruster/azimuth layouts, PWM tables), one way for every node.
Nodes: ``thruster_converter_node``, ``azimuth_allocation_node``, ``pwm_mapper_node``.
"""

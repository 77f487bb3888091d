"""Pure numpy algorithms: filters, models, controllers, allocation.

Nothing under this package imports rclpy (tested by ``test/test_no_ros_in_algorithms.py``).
Conventions: REP-103 frames (world ENU, body FLU), SI units, quaternions as ``[x, y, z, w]``
(the order of ``geometry_msgs/Quaternion`` and ``scipy.spatial.transform.Rotation``).
"""

"""Every topic of the Enbarr graph: name, standard message type, QoS, units and frame.

Standard message types only, so no compiled interface package is needed. SI units and
REP-103 / REP-105 frames everywhere (body ``base_link`` is FLU, world ``odom`` is ENU);
normalized -1..1 values appear only at the operator's stick and at the thruster output.
Every ``frame`` named here is a frame of the profile's tree (``frames`` section,
``enbarr_core.framework.frames``), which ``/tf_static`` and ``/tf`` carry.
The mapping from the messages of the original Enbarr README is in ``docs/interfaces.md``.

Topic names are relative, so a profile's ``namespace`` and ``remappings`` apply to them.
``fast=True`` marks the topics of the control chains (IMU -> thrusters, pose -> azimuths,
scan -> obstacles -> guidance) and the io requests: ``EnbarrNode.create_topic_publisher``
reads it, and between nodes composed in one process these topics travel as direct calls (see
``enbarr_interfaces.links``), and they reach DDS only when something outside the process
subscribes. A fast topic's subscriber runs on its publisher's thread: the scan's perception
on the simulator's thread or the RPLidar driver's reader thread.
"""

from __future__ import annotations

from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import (
    PoseStamped, PoseWithCovarianceStamped, TwistStamped, WrenchStamped)
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Parameter
from rclpy.qos import (
    DurabilityPolicy, HistoryPolicy, QoSProfile, qos_profile_sensor_data, ReliabilityPolicy)
from sensor_msgs.msg import (
    CameraInfo, CompressedImage, FluidPressure, Image, Imu, JointState, Joy, LaserScan,
    BatteryState, MagneticField, PointCloud2, Temperature)
from std_msgs.msg import Bool, Float64, Float64MultiArray, String
from trajectory_msgs.msg import MultiDOFJointTrajectory
from visualization_msgs.msg import MarkerArray

#: Commands and events: nothing may be lost, a short queue.
COMMAND_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE)
#: ``/diagnostics``: every node of a process reports on the same tick, one DiagnosticArray
#: each, so a reader that kept the last 10 lost reports behind the others' whenever its
#: executor was busy (the failsafe node took a reporting attitude filter for a silent one).
DIAGNOSTICS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=200, reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE)
#: High-rate streams: the newest sample matters, late ones are worthless.
SENSOR_QOS = qos_profile_sensor_data
#: States that a late joiner must still learn (the operator mode): the last one is kept.
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL)

BODY_FRAME = 'base_link'
WORLD_FRAME = 'odom'
IMU_FRAME = 'imu_link'
LASER_FRAME = 'laser'
CAMERA_FRAME = 'camera_link'
#: REP-103's optical frame of the camera: z forward, x right, y down.
CAMERA_OPTICAL_FRAME = 'camera_optical_frame'

#: The frame tree on DDS, as tf2 names the topics (``tf2_msgs/msg/TFMessage``; no
#: ``TopicSpec``: PyPI has no tf2_msgs to name the class). QoS as tf2's broadcasters offer.
TF_TOPIC = '/tf'
TF_STATIC_TOPIC = '/tf_static'
TF_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE)
TF_STATIC_QOS = LATCHED_QOS


@dataclass(frozen=True)
class TopicSpec:
    """One topic of the contract."""

    name: str
    msg_type: type
    qos: QoSProfile
    units: str
    frame: str
    description: str
    fast: bool = False

    @property
    def type_name(self) -> str:
        """``pkg/msg/Type`` as used in bags and by ``ros2 topic``."""
        module = self.msg_type.__module__.split('.')[0]
        return f'{module}/msg/{self.msg_type.__name__}'


IMU_RAW = TopicSpec(
    'imu/data_raw', Imu, SENSOR_QOS,
    'angular_velocity rad/s, linear_acceleration m/s^2 (specific force, +9.81 z at rest)',
    IMU_FRAME, 'Raw IMU sample from the IMU plugin; orientation_covariance[0] = -1 (none).',
    fast=True)
IMU_MAG = TopicSpec(
    'imu/mag', MagneticField, SENSOR_QOS, 'tesla', IMU_FRAME,
    'Magnetometer sample from the IMU plugin, same stamp as imu/data_raw.', fast=True)
IMU = TopicSpec(
    'imu/data', Imu, SENSOR_QOS,
    'orientation (quaternion, odom ENU <- imu_link), rad/s bias-corrected, m/s^2',
    IMU_FRAME, 'Filtered IMU with covariances, from the orientation filter.', fast=True)
SURFACE_TWIST = TopicSpec(
    'surface_command/twist', TwistStamped, COMMAND_QOS, 'm/s, rad/s', BODY_FRAME,
    'Velocity the operator or a mission asks for. Stamped: stale commands are refused.')
SURFACE_STOP = TopicSpec(
    'surface_command/stop', Bool, LATCHED_QOS, 'true = stop', '',
    "The station's stop (latched), with named command sources only: true holds the velocity "
    'goal at zero whatever any source sends, until false. A true is taken from any '
    'publisher; a false only from a single one.')
SURFACE_ACTIVE_SOURCE = TopicSpec(
    'surface_command/active_source', String, LATCHED_QOS, 'source name', '',
    'Which named command source drives the velocity goal (latched), with named sources only: '
    'a source name, "stop" (the station stop is set) or "none" (no source is live: the goal '
    'is zero).')
SURFACE_IO = TopicSpec(
    'surface_command/io', Parameter, COMMAND_QOS, 'plugin-defined', '',
    'IO request from the surface: name = executor, value = typed request.')
TRAJECTORY_REQUEST = TopicSpec(
    'trajectory_request', TwistStamped, COMMAND_QOS, 'm/s, rad/s', BODY_FRAME,
    'Validated velocity goal from the command receiver (zero on failsafe).', fast=True)
PILOT_MODE = TopicSpec(
    'pilot_mode', String, LATCHED_QOS, 'mode name', '',
    "The ROV's pilot mode (latched): manual, stabilize, depth_hold or velocity. Requested "
    'as an io request to executor pilot_mode with the mode as string_value.')
PILOT_MODE_REASON = TopicSpec(
    'pilot_mode/reason', String, COMMAND_QOS, 'text', '',
    'Why a pilot mode request was refused, or why the mode fell back (depth_hold -> '
    'stabilize on a stale depth).')
IO_REQUEST = TopicSpec(
    'io_request', Parameter, COMMAND_QOS, 'plugin-defined', '',
    'Validated IO request: name = executor (e.g. manipulator, gpio_12), value = request.',
    fast=True)
IO_STATE = TopicSpec(
    'io_state', Parameter, COMMAND_QOS, 'plugin-defined', '',
    'State of an IO plugin after it acted: name = executor, value = new state.',
    fast=True)
FORCE_COMMAND = TopicSpec(
    'force_command', WrenchStamped, SENSOR_QOS, 'N, N m', BODY_FRAME,
    'Generalized force tau the controller asks of the allocation (called '
    '"trajectory_corrected" before; see docs/interfaces.md).', fast=True)
THRUSTER_COMMANDS = TopicSpec(
    'thruster_commands', JointState, SENSOR_QOS, 'normalized -1..1 (effort)', BODY_FRAME,
    'Per-thruster command: name[i] = thruster, effort[i] = -1 (full reverse) .. 1 (full '
    'forward). header.stamp = stamp of the IMU sample it answers.', fast=True)
THRUSTER_OUTPUT = TopicSpec(
    'thruster_output', JointState, SENSOR_QOS, 'normalized -1..1 (effort)', BODY_FRAME,
    'What a thruster plugin actually applied, including neutral on timeout and shutdown.',
    fast=True)
THRUSTER_SENSORS = TopicSpec(
    'thruster_sensors', JointState, SENSOR_QOS, 'rad/s (velocity), A (effort)', BODY_FRAME,
    "Per-thruster feedback (the Enbarr README's thruster_sensors): velocity[i] = shaft speed "
    'of thruster name[i], signed like its command; effort[i] = its current, NaN where the ESC '
    'does not measure it.', fast=True)
SIM_IMU = TopicSpec(
    'sim/imu', Imu, SENSOR_QOS, 'as imu/data, exact', IMU_FRAME,
    'Simulator ground truth at the IMU: true orientation, rate and specific force.',
    fast=True)
PRESSURE_FRAME = 'pressure_link'
PRESSURE = TopicSpec(
    'pressure', FluidPressure, SENSOR_QOS, 'Pa', PRESSURE_FRAME,
    'Absolute water pressure at the depth sensor (MS5837-30BA driver).')
PRESSURE_TEMPERATURE = TopicSpec(
    'pressure/temperature', Temperature, SENSOR_QOS, 'degC', PRESSURE_FRAME,
    "Water temperature at the depth sensor (the pressure chip's own thermometer).")
DEPTH = TopicSpec(
    'depth', PoseWithCovarianceStamped, SENSOR_QOS, 'm', WORLD_FRAME,
    'Depth of the pressure sensor as a pose: position.z = -depth (odom ENU, z up), with '
    'its variance in covariance[14]; every other axis unobserved (variance 1e9), orientation '
    'identity. The form a pose-fusing filter (robot_localization) takes a depth in.')
SIM_ODOMETRY = TopicSpec(
    'sim/odometry', Odometry, SENSOR_QOS, 'm, m/s, rad/s', WORLD_FRAME,
    'Simulator ground truth pose (odom ENU) and body velocity (child frame base_link).',
    fast=True)
SIM_THRUST = TopicSpec(
    'sim/thrust', JointState, SENSOR_QOS, 'N (effort)', BODY_FRAME,
    'Thrust each simulated thruster produces, applied by the simulator.', fast=True)
RECORDER_CONTROL = TopicSpec(
    'recorder/control', String, COMMAND_QOS, 'start | stop', '',
    'Start or stop the recorder (enbarr_core.recording.recorder_node): stop closes the bag, '
    'start opens a new one beside it. Not latched: a restarted recorder must not replay an '
    'old word. Refusals and the state are on /diagnostics.')
DIAGNOSTICS = TopicSpec(
    '/diagnostics', DiagnosticArray, DIAGNOSTICS_QOS, '', '',
    'Counters and states of nodes (rejected commands, failsafe, timeouts).')

# -- 3-DOF surface vessels: motion capture, observer, guidance, DP control, azimuths, PWM --
MOCAP_POSE = TopicSpec(
    'mocap/pose', PoseStamped, SENSOR_QOS, 'm, quaternion', WORLD_FRAME,
    'Pose of base_link in odom from motion capture (the manual\'s Qualisys "GPS"); the '
    "tracked body's own frame is the tree's mocap_body.", fast=True)
JOY = TopicSpec(
    'joy', Joy, SENSOR_QOS, 'normalized -1..1 axes, 0/1 buttons', '',
    'Operator joystick, in the layout the profile names (joy.layout: enbarr_plugins.joystick.'
    'layouts).')
OBSERVER_ODOMETRY = TopicSpec(
    'observer/odometry', Odometry, SENSOR_QOS, 'm, rad; m/s, rad/s', WORLD_FRAME,
    'Observer estimate: pose eta_hat in odom, body velocity nu_hat (child base_link).',
    fast=True)
OBSERVER_BIAS = TopicSpec(
    'observer/bias', WrenchStamped, SENSOR_QOS, 'N, N m', WORLD_FRAME,
    'Observer estimate of the slowly varying force bias (current, wind), world frame.',
    fast=True)
OBSERVER_AGE = TopicSpec(
    'observer/measurement_age', Float64, SENSOR_QOS, 's', '',
    'Time since the observer last accepted a pose; grows while it dead-reckons.', fast=True)
JOY_CONNECTED = TopicSpec(
    'joy/connected', Bool, LATCHED_QOS, '', '',
    "Joystick driver's connection state (latched), republished as a heartbeat at least "
    'every joy_timeout/2 while connected; False at once on disconnect. The joystick-loss rule '
    "'connection' of dp_control listens to it (drivers that publish joy only on change).")
MODE = TopicSpec(
    'mode', String, LATCHED_QOS, '', '',
    'Operator mode: manual, automatic or guidance (latched), from the controller.')
GUIDANCE_REFERENCE = TopicSpec(
    'guidance/reference', MultiDOFJointTrajectory, SENSOR_QOS,
    'm, rad; m/s, rad/s; m/s^2, rad/s^2', WORLD_FRAME,
    'Guidance reference for the estimate of the same stamp: one point of joint base_link with '
    'transforms[0] = eta_d (x, y, yaw quaternion; odom), velocities[0] = nu_d and '
    'accelerations[0] = nu_d_dot (body frame). A pose component that is not fed back (line '
    'of sight tracks surge/sway velocity only) is NaN. See '
    'enbarr_core.guidance.guidance_node.reference_to_msg.', fast=True)
GUIDANCE_AVOIDANCE = TopicSpec(
    'guidance/avoidance', Float64MultiArray, SENSOR_QOS, 's; m', '',
    'What the collision avoidance did for each estimate while it is on (automatic or '
    'guidance): stamps of the estimate and of the obstacles used, safety filter time, '
    'binding constraints, infeasible, min barrier, engaged, blind. layout.dim[0].label = the '
    'comma-joined field names; encoding enbarr_interfaces.avoidance, docs/interfaces.md.',
    fast=True)
CONTROL_AVOIDANCE = TopicSpec(
    'control/avoidance', Float64MultiArray, SENSOR_QOS, 's; N', '',
    'What the force-level collision avoidance (avoidance.level force) did to each force the '
    'DP controller sent outside manual: the fields of guidance/avoidance (encoding '
    'enbarr_interfaces.avoidance), min_barrier being the hull clearance less the safety '
    'radius and blind meaning obstacles older than avoidance.staleness.', fast=True)
GUIDANCE_PATH_AVAILABLE = TopicSpec(
    'guidance/path_available', Bool, LATCHED_QOS, '', '',
    'Whether the guidance node has a path or waypoint to follow (the controller refuses '
    'guidance without one); latched.')
AZIMUTH_COMMANDS = TopicSpec(
    'azimuth_commands', JointState, SENSOR_QOS, 'effort N (signed thrust), position rad',
    BODY_FRAME, 'Per-azimuth thrust and angle from the allocation.', fast=True)
ALLOCATION_DELIVERED = TopicSpec(
    'allocation/delivered', WrenchStamped, SENSOR_QOS, 'N, N m', BODY_FRAME,
    'Force the allocation can deliver (less than asked when saturated).', fast=True)
PWM_DUTY = TopicSpec(
    'pwm/duty_cycle', Float64MultiArray, SENSOR_QOS, 'duty cycle %', '',
    'PWM duty cycle per channel, data[i] for channel i: <azimuth>/motor, <azimuth>/servo for '
    'each azimuth in azimuth_names order (also the output order of the Arduino); '
    'layout.dim[0]: label duty_cycle_percent, size = stride = number of channels. Within '
    'pwm.duty_min_percent .. pwm.duty_max_percent of the profile.', fast=True)
PWM_DUTY_LABEL = 'duty_cycle_percent'
"""``layout.dim[0].label`` of a ``PWM_DUTY`` message: what its ``data`` holds."""
SIM_AZIMUTH_COMMAND = TopicSpec(
    'sim/azimuth_command', JointState, SENSOR_QOS, 'effort N, position rad', BODY_FRAME,
    'Thrust and angle the simulated Arduino sets on the simulated azimuths.', fast=True)
# -- perception (device drivers) --
SCAN = TopicSpec(
    'scan', LaserScan, SENSOR_QOS, 'm, rad', LASER_FRAME,
    "One lidar revolution in the lidar's own frame, as a real driver publishes it: "
    'angle_min..angle_max counter-clockwise from +x; REP-117: -inf too close, +inf no '
    "return, NaN no sample. Where the lidar sits is the frame tree's (base_link -> laser on "
    '/tf_static); consumers transform the scan with it.', fast=True)
OBSTACLES = TopicSpec(
    'obstacles', PointCloud2, SENSOR_QOS, 'm, m/s, m^2', WORLD_FRAME,
    'Tracked obstacles, one point per obstacle (a capsule: segment x,y-x2,y2 with radius), '
    'with velocity and covariance; header.stamp = stamp of the measurement it came from. '
    'Encoding: enbarr_interfaces.obstacles, docs/interfaces.md "Obstacles".', fast=True)
OBSTACLES_FUSED = TopicSpec(
    'obstacles/fused', PointCloud2, SENSOR_QOS, 'm, m/s, m^2', WORLD_FRAME,
    'The obstacles of obstacles with the class of the camera detections they matched (the '
    'fusion node): the same encoding with its class_id and class_score fields, the same '
    'stamps; the collision avoidance reads it in place of obstacles (a remapping).',
    fast=True)
OBSTACLE_MARKERS = TopicSpec(
    'obstacles/markers', MarkerArray, SENSOR_QOS, 'm', WORLD_FRAME,
    'The obstacles drawn for a viewer (Foxglove, RViz): not for machines, read obstacles.')
CAMERA_IMAGE = TopicSpec(
    'camera/image_raw', Image, SENSOR_QOS, 'pixels (bgr8)', CAMERA_OPTICAL_FRAME,
    'Camera frames as captured (OpenCV, V4L2 or a video file).')
CAMERA_COMPRESSED = TopicSpec(
    'camera/image_raw/compressed', CompressedImage, SENSOR_QOS, 'JPEG', CAMERA_OPTICAL_FRAME,
    "camera/image_raw as JPEG, as image_transport's compressed plugin publishes it (format "
    "'bgr8; jpeg compressed bgr8'), same stamp; what the recorder keeps by default.")
CAMERA_INFO = TopicSpec(
    'camera/camera_info', CameraInfo, SENSOR_QOS, 'pixels', CAMERA_OPTICAL_FRAME,
    'Calibration of camera/image_raw, same stamp (ROS camera_info YAML).')
#: The camera driver's sensor_msgs/srv/SetCameraInfo: stores a calibration in its
#: calibration_file and publishes it from then on (camera_info_manager's name, which ROS's
#: cameracalibrator "commit" calls).
CAMERA_SET_INFO = 'camera/set_camera_info'
VESSEL_CLAIMS = TopicSpec(
    '/enbarr/claims', String, LATCHED_QOS, 'JSON', '',
    'Claim of a running bringup group (latched): {"nodes", "host", "pid", "started_ns"}; a '
    'second run with the same node names refuses at start or, when they missed each other, '
    'the later one stops (docs/architecture.md, Safety).')
# -- vision --
DETECTIONS = TopicSpec(
    'detections', PointCloud2, SENSOR_QOS, 'pixels', CAMERA_OPTICAL_FRAME,
    'Objects found in a camera image, one point per box (class_id, score, x_min, y_min, '
    "x_max, y_max in the image's pixels); header = the image's header, also when nothing "
    'was found. Encoding: enbarr_interfaces.detections, docs/interfaces.md "Detections".')
DETECTION_IMAGE = TopicSpec(
    'detections/image', Image, SENSOR_QOS, 'pixels (bgr8)', CAMERA_OPTICAL_FRAME,
    'The image with its detections drawn, for a viewer (built only while one subscribes).')
LEAK = TopicSpec(
    'leak', Bool, LATCHED_QOS, '', '',
    'Hull leak (latched): true after the leak sensor read wet for its debounce time, until it '
    'read dry for its dry_hold time (leak_gpio driver); published on every change.')
BATTERY = TopicSpec(
    'battery', BatteryState, SENSOR_QOS, 'V, A (negative while discharging), 0..1', '',
    'Battery voltage, current and state of charge from the power monitor (ina219_battery '
    'driver); unmeasured fields NaN.')
FAILSAFE_ACTION = TopicSpec(
    'failsafe/action', String, LATCHED_QOS, 'action name', '',
    'The action the failsafes ask for (latched): none, warn, stabilize, manual, surface or '
    'neutral: the most severe of the active ones (control.failsafes). The velocity loop '
    'applies it.')
FAILSAFE_ACTIVE = TopicSpec(
    'failsafe/active', String, LATCHED_QOS, 'text', '',
    'The active failsafes (latched), each with its action, the time it tripped [s of the '
    'node clock] and why; "none" when none is.')
HULL_PRESSURE = TopicSpec(
    'hull/pressure', FluidPressure, SENSOR_QOS, 'Pa', '',
    'Air pressure inside the electronics enclosure (a rising one: a seal letting water in).')
HULL_TEMPERATURE = TopicSpec(
    'hull/temperature', Temperature, SENSOR_QOS, 'degC', '',
    'Air temperature inside the electronics enclosure.')

ALL_TOPICS: tuple[TopicSpec, ...] = (
    IMU_RAW, IMU_MAG, IMU, SURFACE_TWIST, SURFACE_STOP, SURFACE_ACTIVE_SOURCE, SURFACE_IO,
    TRAJECTORY_REQUEST, PILOT_MODE, PILOT_MODE_REASON, IO_REQUEST, IO_STATE,
    FORCE_COMMAND, THRUSTER_COMMANDS, THRUSTER_OUTPUT, THRUSTER_SENSORS, SIM_IMU, SIM_ODOMETRY,
    SIM_THRUST, DIAGNOSTICS, RECORDER_CONTROL, MOCAP_POSE, JOY, JOY_CONNECTED,
    OBSERVER_ODOMETRY, OBSERVER_BIAS,
    OBSERVER_AGE, MODE,
    GUIDANCE_REFERENCE, GUIDANCE_AVOIDANCE, CONTROL_AVOIDANCE, GUIDANCE_PATH_AVAILABLE,
    AZIMUTH_COMMANDS,
    ALLOCATION_DELIVERED,
    PWM_DUTY, SIM_AZIMUTH_COMMAND, SCAN, OBSTACLES, OBSTACLES_FUSED, OBSTACLE_MARKERS,
    CAMERA_IMAGE, CAMERA_COMPRESSED, CAMERA_INFO, VESSEL_CLAIMS, DETECTIONS, DETECTION_IMAGE,
    PRESSURE, PRESSURE_TEMPERATURE, DEPTH, LEAK, BATTERY, FAILSAFE_ACTION, FAILSAFE_ACTIVE,
    HULL_PRESSURE, HULL_TEMPERATURE)

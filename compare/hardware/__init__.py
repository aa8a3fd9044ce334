"""Hardware bridge: the same control loop on a real Jaco² and depth camera through ROS 1 (docs/hardware.md).

* :mod:`compare.hardware.ros_io` — :class:`~compare.hardware.ros_io.RosRobotIO`, the ROS backend of
  :class:`~compare.loop.robot_io.RobotIO` (kinova-ros driver topics, depth camera, command stream, watchdog);
* :mod:`compare.hardware.safety` — velocity/acceleration clamps, watchdog, start-up checks (no ROS);
* :mod:`compare.hardware.exposure` — refuses a master or node reachable beyond loopback (no ROS);
* :mod:`compare.hardware.publisher_watch` — who else publishes on the driver's topics (master API);
* :mod:`compare.hardware.validation` — checks of every message read (sizes, NaN, encodings, stamps, names);
* :mod:`compare.hardware.master_api` — the master calls the bridge makes itself, with a timeout;
* :mod:`compare.hardware.conversions` — units at the ROS boundary (deg/s, mm, quaternions; no ROS);
* :mod:`compare.hardware.sensing` — depth-space obstacle distance on live frames;
* :mod:`compare.hardware.run` — :func:`~compare.hardware.run.run_hardware`, behind ``tpik-compare hw``;
* :mod:`compare.hardware.standin` — a driver + camera stand-in backed by the MuJoCo simulation;
* :mod:`compare.hardware.ros_env` — how rospy is reached and ``kinova_msgs/JointVelocity`` generated;
* ``msg/JointVelocity.msg`` — our copy of the driver's message; ``launch/jaco2_tpik.launch`` — bring-up.

Nothing here imports ROS at module import time: the core project installs and tests without it.
"""

"""ROS 2 output over Zenoh, as an rmw_zenoh node publishes (no ROS installation needed).

msgdefs   message definitions, DDS type names and RIHS01 type hashes (shipped, not fetched)
frames    NED/FRD -> ENU/FLU (REP-103, REP-145)
messages  NavSolution -> Imu, NavSatFix, Odometry, DiagnosticArray as CDR (rosbags)
rmw       rmw_zenoh's key expressions, liveliness tokens, attachment and GID; Ros2Node
names     ROS name checks and resolution (used by the config)

Modules are imported by name (``navd.io.ros2.messages``) so that a daemon without [ros2]
never loads the serialiser.
"""

"""machine_ctrl: controller core (kinematics, servo laws, dual-stage coupling, contour error),
its ROS 2 nodes and the ``machine-ctrl`` command-line tool. See README.md and design.md."""

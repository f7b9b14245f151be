"""Ground: the machine model (config, URDF, kinematics, units)."""

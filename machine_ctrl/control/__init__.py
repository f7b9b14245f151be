"""ROS-free control laws behind one interface: law.py (the ControlLaw protocol),
registry.py (the laws by the name a machine YAML gives), one module per law, filters.py and
lugre.py (building blocks), servo.py (law + feed-forward per axis) and dual_stage.py."""

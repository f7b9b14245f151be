"""ROS-free control laws behind one interface: law.py (the ControlLaw protocol),
registry.py (the laws by the name a machine YAML gives), one module per law, filters.py and
lugre.py (building blocks), servo.py (law + feed-forward per axis), dual_stage.py,
contour_coupling.py (cross-coupled contour control), stepping.py (the lock-step answer),
h2_synthesis.py; midranging.py, deflection.py and feed_force.py are controllers with their
own step interfaces."""

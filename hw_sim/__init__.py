"""Plant models, the simulator, its lock-step and paced session logic and the offline runner
(issue [2/7]); the node is machine_ctrl/ros/hw_sim_node.py."""

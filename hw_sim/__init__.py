"""Plant models and the simulated hardware node (issue [2/7])."""

"""The robot: FR3 kinematic model (fr3), the RCM servo (servo), commanded trajectories and the
paper's protocols (trajectory, protocols), and `motion.simulate` tying them into ground truth."""

"""calbench.bench.model: the robot model: its description, parameters, MjModel wrapper, loop kinematics, shapes, effects."""

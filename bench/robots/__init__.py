"""calbench.bench.robots: robots from elsewhere: URDF import, its overlay, the robot check."""

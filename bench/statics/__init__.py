"""calbench.bench.statics: exact static equilibrium of the closed-loop robot, one command or many at once."""

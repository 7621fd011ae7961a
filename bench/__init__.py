"""calbench.bench — the virtual test bench: robot model, exact statics, laser tracker,
calibration campaigns and their MCAP log."""

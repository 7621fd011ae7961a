"""calbench.bench.campaign: a calibration campaign: posed unloaded and loaded, measured, logged."""

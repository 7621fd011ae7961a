"""calbench.bench.tracker: the laser tracker: frames, noise models, visibility, a campaign's readings."""

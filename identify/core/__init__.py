"""calbench.identify.core: what every estimator shares: observations, whitening, the forward model, least squares, identifiability."""

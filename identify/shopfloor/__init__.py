"""calbench.identify.shopfloor: real readings in: the import and the tracker's pose."""

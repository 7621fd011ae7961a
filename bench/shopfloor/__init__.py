"""calbench.bench.shopfloor: readings from a real tracker: the readings CSV and logs made from it."""

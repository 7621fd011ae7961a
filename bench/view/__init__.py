"""calbench.bench.view: the Rerun view of a campaign: what it draws, its pages, the parameter chart."""

"""calbench.identify.report: what a person reads: the identify table and JSON, the HTML report."""

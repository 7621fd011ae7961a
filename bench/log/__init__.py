"""calbench.bench.log: the campaign log (MCAP) and the identification report: written, read, scanned, recovered."""

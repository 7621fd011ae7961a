"""calbench.identify — elastostatic identification, experiment design and the discrepancy
workflow. Builds on `bench`; never imported by it."""

"""calbench.identify.runtime: where pieces of work run: this process or Dask, and what travels to a worker."""

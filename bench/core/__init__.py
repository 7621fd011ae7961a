"""calbench.bench.core: the bench's plumbing: errors, checked outputs, progress, shipped files, display units."""

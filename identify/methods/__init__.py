"""calbench.identify.methods: the estimators: one-step, two-step, two-step iterated."""

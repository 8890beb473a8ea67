"""The benchmarks' harness, apart from what a node runs: plants in truth (a fin with effects its
controller is not told, and what the estimator would read of it), the optimiser scored against the
truth's optimum, and a fish swum in fish time with every strategy.  Used by ``benchmarks/`` and the
tests; nothing in the nodes imports it."""

"""The recursive estimator: [RA-SRIVC] Algorithm 2 over the compiled per-sample kernel, and what it reports."""

"""Simulation with known truth: the papers' plants and controllers (plants), the time-varying plant simulator
(simulate), named scenarios written as bags (scenarios), simulated machine recordings (fleetsim) and seeded
estimator experiments (experiments). Outside the numerical core: it may read params files and write bags."""

"""Closed-loop evaluation of latent-action models with the simulated teleoperator.

kinematic: the paper's integration q <- q + phi(z*, s) dt, for fast sweeps;
graph: the full node graph (bridge with MuJoCo, detector, controller, teleoperator) in processes;
metrics/plots: per-episode figures, CSV/JSON reports and PNG plots.
"""

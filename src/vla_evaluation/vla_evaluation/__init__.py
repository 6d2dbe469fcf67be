"""Evaluation: the simulated teleoperator, the scripted demonstrator, closed-loop evaluation, the
paper's experiments and the demo.
"""

"""
Aggregates of runs and the probability of improvement (``statistics``), and their stratified bootstrap
confidence intervals (``bootstrap``), as ``rliable`` computes them.
"""

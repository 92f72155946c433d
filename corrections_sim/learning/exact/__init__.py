"""The exact family: the posterior on the plan atlas's cells, refined where it lives.

:mod:`.bayes` (the likelihoods, posterior and moments on a grid, also the exact reference's),
:mod:`.cells` (the refinable cells and their trapezoid weights), :mod:`.learners` (EX-C,
EX-CL).
"""

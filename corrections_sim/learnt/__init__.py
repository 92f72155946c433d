"""Learnt features (FERL): a small network trained on a person's feature traces by a
deterministic L-BFGS (:mod:`.training`, :mod:`.lbfgs`), planned over through the optimizer's
learnt-feature slots."""

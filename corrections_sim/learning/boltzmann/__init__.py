"""The Boltzmann family: a Gaussian posterior under a Boltzmann model of corrections
(:mod:`.posterior`) and its learner (:mod:`.learners`: BP)."""

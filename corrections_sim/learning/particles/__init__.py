"""The particle family: a weighted sample of θ, moved and reweighed by every correction
(:mod:`.cloud`), and its learners (:mod:`.learners`: PF-C, AL-PF)."""

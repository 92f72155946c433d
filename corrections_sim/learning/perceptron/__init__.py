"""The perceptron family: the Preference Perceptron's update (eq. B5, :mod:`.update`) and its
learners (:mod:`.learners`: PP, PP-C, PP-MAX)."""

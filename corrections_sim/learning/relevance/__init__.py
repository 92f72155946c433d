"""The relevance family: whether a correction is about what the robot knows.

:mod:`.judge` (β̂ from how much of a correction the robot's features explain), :mod:`.learners`
(KF-CR, KF-CRP, PP-R), :mod:`.expansion` (KF-CRX: learning the feature it lacks).
"""

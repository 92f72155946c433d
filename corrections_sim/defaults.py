"""The learners each command runs when none is named: the one place that says which (by
registered name; :mod:`corrections_sim.learning.roster` registers the built-in ones). It
imports nothing, so a command line that only shows its help stays quick."""

#: The robot we recommend (docs/decision.md): the exact posterior over what the person wants,
#: how they correct, how noisy they are (EX-M, docs/person-models.md). It is calibrated where
#: calibration can be tested (simulation-based calibration, docs/sbc.md) and the most accurate
#: learner in every study whose person it can represent. Every command below meets it first.
RECOMMENDED = "EX-M"

#: The learners each command runs when none is named: the one place that says which.
DEFAULTS: dict[str, tuple[str, ...]] = {
    # A study file without ``learners`` (``run study``): the recommended robot beside the
    # paper's learner with the calibrated correction model (the others are opt-in:
    # ``learners`` in a study file, ``--learners``). Such a study gets the plan atlas the
    # recommended robot needs unless it says ``atlas = false``.
    "study": (RECOMMENDED, "KF-C"),
    # Who learns in a browser session (``interact``, ``interact --mode physical``,
    # ``Session.start``).
    "session": (RECOMMENDED,),
    # Whose runs ``reference`` judges against the exact posterior of its own model. Not the
    # recommended robot: it is that exact posterior (``reference`` answers "how far is this
    # approximation from exact Bayes?"); its own check is ``run sbc``.
    "reference": ("KF-C",),
    # Whose run ``video`` animates.
    "video": (RECOMMENDED,),
    # What ``replay`` replays a session's corrections through (and the session's own).
    "replay": (RECOMMENDED, "PP", "KF", "KF-C", "BP"),
}

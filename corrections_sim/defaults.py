"""The learners each command runs when none is named: the one place that says which (by
registered name; :mod:`corrections_sim.learning.roster` registers the built-in ones). It
imports nothing, so a command line that only shows its help stays quick."""

#: The learners each command runs when none is named: the one place that says which.
DEFAULTS: dict[str, tuple[str, ...]] = {
    # A study file without ``learners`` (``run study``): the paper's three; the others are
    # opt-in (``learners`` in a study file, ``--learners``).
    "study": ("PP", "KF", "AL"),
    # Who learns in a browser session (``interact``, ``Session.start``).
    "session": ("KF-CL",),
    # Whose runs ``reference`` judges against the exact posterior.
    "reference": ("KF-C",),
    # Whose run ``video`` animates.
    "video": ("KF",),
    # What ``replay`` replays a session's corrections through (and the session's own).
    "replay": ("PP", "KF", "KF-C", "BP"),
}

"""A correction session: the robot plans, a person (or a simulated user) corrects, a learner
updates, every correction logged first in a SQLite log that replays through any learners."""

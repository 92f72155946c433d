"""How people correct a plan: correction models (registered by name) and simulated users."""

# The physical person and its correction model register themselves on import.
from corrections_sim.people import physical  # noqa: F401

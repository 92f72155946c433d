"""The optimizer of plans ξ*(θ, E): features Φ, the trajectory optimizer, its compiled code and
the machine's cache, and risk-sensitive deployment (A2–A4). Imports only
:mod:`corrections_sim.scene` and the core; where plans come from is :mod:`corrections_sim.plans`."""

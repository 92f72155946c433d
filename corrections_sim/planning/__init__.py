"""Plans ξ*(θ, E): features Φ, the trajectory optimizer, memoized plans and regret, and
risk-sensitive deployment (A2–A4). Imports only :mod:`corrections_sim.scene` and the core."""

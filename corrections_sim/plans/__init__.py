"""Where plans come from, apart from the planner that solves them."""

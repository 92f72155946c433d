"""How people correct a plan: correction models (registered by name) and simulated users."""

"""Learnt features: a small network trained on a person's feature traces."""

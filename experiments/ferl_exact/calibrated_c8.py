"""A diagnosis, not a choice (docs/learnt-features.md, "Exact at k + 1 with one teaching per
person"): the taught feature passed through the monotone calibration
g_c(y) = (e^{cy} − 1) / (e^c − 1) with c = 8, the c under which learnt features fit `human`
best, read off `human` itself, which a robot must not do. Registered as
``taught-human-1-c8`` for only_c8.toml and also_c8.toml: how much a better shape of the same
feature would buy an exact learner."""

import math
from pathlib import Path

import casadi as ca

from corrections_sim.learnt.training import load
from corrections_sim.planning.features import FEATURES, register_feature

TAUGHT = load(Path(__file__).with_name("taught-human-1.json"))
C = 8.0

if "taught-human-1-c8" not in FEATURES:

    @register_feature("taught-human-1-c8")
    def calibrated(w):
        y = TAUGHT.network.expression(w, ca.DM(TAUGHT.weights))
        return (ca.exp(C * y) - 1.0) / (math.exp(C) - 1.0)

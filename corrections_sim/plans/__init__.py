"""Where plans come from, apart from the optimizer that solves them: a run's memoized plans
and the person's (:mod:`.book`, with regret), the plan atlas (:mod:`.atlas`), the plans
between its nodes (:mod:`.between`) and read off it (:mod:`.interpolation`), each on disk
under its key. Learners ask for plans (``ctx.book``); none builds a store."""

"""People scripted through chromium with Playwright, for the tests and the benchmarks (the
``dev`` extra; run from the clone, not in the wheel): a pointer and keys that wait on the
page's state, labelled corrections, a teacher of feature traces."""

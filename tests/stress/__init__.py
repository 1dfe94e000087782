"""The stress harness behind `evsplat bench stress`: property-based stress over every numeric
component, and SIGKILL trials.

Each component has a case generator ``<component>_cases(rng, n)`` yielding :class:`Case`\\ s that
mix the edge cases named in issue 8 (floods in one pixel, 2^40 µs offsets, empty windows,
extreme contrasts, 180° rotations, zero-variance images, zero depth, degenerate Gaussians, ...)
with random parameters. The invariant checked for every case:

* ``expect="finite"``: the case returns arrays (outputs and gradients) that are all finite and
  pass the case's own oracle checks (e.g. event counts add up, ESI matches numpy);
* ``expect="error"``: the input is invalid and must raise a clear error, i.e. an EvsplatError or
  ValueError with a non-empty one-line message; silently accepting it is a failure.

``--kill-trials N`` SIGKILLs `evsplat train` / `simulate --tiny` / `export` at random moments and
checks that every file a later command would read is absent or complete, and that `--resume`
continues from the newest complete checkpoint. The default tests run a small subset of both
(tests/test_stress_fast.py).

Modules: ``harness`` (Case, Tally, check_case), the case generators ``cases_events`` (event
core, camera spline), ``cases_losses`` (losses, colour fit and metrics) and ``cases_model``
(Gaussian activations, rasterizer), ``suite`` (the component table and the bench's table) and
``kill`` (SIGKILL trials).
"""

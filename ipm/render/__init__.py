"""Mitsuba 3 rendering: differentiable silhouettes (optimisation) and textured references (synth).

Modules here import Mitsuba lazily: the variant must be set by the entry point first
(``ipm.runtime.set_mitsuba_variant``).
"""
